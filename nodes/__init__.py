"""The processes of simecs: hub, proxy, simulator (and its workers), hot-feedback, recorder; the
`simecs` CLI with its `up`, `replay` and `export` commands."""
