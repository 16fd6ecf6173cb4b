"""Matplotlib figures; imported only when a command is asked for a plot."""
