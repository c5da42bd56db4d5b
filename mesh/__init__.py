"""The protocol of simecs, and every rule more than one process needs: keys, messages, phases, frames,
columns, shape geometry, codec, schema, mesh configuration and the node runtime, in one place."""
