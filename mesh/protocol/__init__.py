"""The protocol: what a client written from docs/PROTOCOL.md alone must agree with (keys, messages,
phases, frames, columns, limits, the codec and the schema generated from them)."""
