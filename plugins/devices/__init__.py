"""Real device adapters: the Intel RealSense camera, the Vive tracker (OpenVR), a UR robot over
ur-rtde (driver and motion checks), cameras that read image files. Their stages are in ``stages/``;
each has a simulated twin in plugins/sim."""
