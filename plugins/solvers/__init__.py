"""solvers stages and their libraries."""
