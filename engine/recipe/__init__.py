"""The recipe: its pydantic model (:mod:`engine.recipe.model`), the YAML source with line numbers
for error messages (:mod:`engine.recipe.yaml_source`), unit checks on parameter names
(:mod:`engine.recipe.unit_checks`) and the grammar of zenoh endpoints a recipe may name
(:mod:`engine.recipe.endpoint_syntax`). Imports nothing of transport, run, recording or cli."""
