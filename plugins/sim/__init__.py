"""sim stages and their libraries."""
