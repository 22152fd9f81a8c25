"""Small generic stages: synthetic, transformed and summarised clouds, and a trigger."""
