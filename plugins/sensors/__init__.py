"""Sensors: real device adapters (RealSense, Vive tracker) and file-based cameras."""
