"""Everything more than one process shares: the protocol (`protocol/`), the rules several processes
compute alike (`rules/`), the plumbing every process joins the mesh with (`process/`), and the client
side (`client`, `batch`)."""
