"""Robot models: physics built in Exudyn and their descriptions as data."""
