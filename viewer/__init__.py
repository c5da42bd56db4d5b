"""The viser web client; of simecs it imports only simecs.mesh."""
