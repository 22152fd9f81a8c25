"""sensors stages and their libraries."""
