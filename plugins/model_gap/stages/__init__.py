"""The model-gap stages: ``measurement_campaign`` (drive a pose campaign, record robot and tracker)
and ``model_gap`` (run the workflow on what the campaign measured)."""
