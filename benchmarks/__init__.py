"""`simecs bench NAME`: the figures each speed target is measured by (model, service, recorder,
viewer). Each module's `run(json_out)` prints a human table and, with `json_out`, one JSON line last."""
