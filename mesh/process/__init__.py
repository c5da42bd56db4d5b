"""How a process joins the mesh and stays up: the node runtime, configuration, service seals, access
rules, bounded workers, the hub link, CPU affinity, logs, crash-safe files."""
