"""The registration stage: ``matcher`` (template to scene, with its quality test)."""
