"""The `simecs` command (cli) and its tools that are not nodes: runs and sweeps from the command line
(batch), a run's results as a table (export)."""
