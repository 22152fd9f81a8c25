"""actions stages and their libraries."""
