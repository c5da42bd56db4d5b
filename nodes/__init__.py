"""The processes of simecs: proxy, simulator, hot-feedback, recorder, replay, and the CLI that starts them."""
