"""The zenoh protocol of simecs: keys, messages, codecs and the node runtime, in one place."""
