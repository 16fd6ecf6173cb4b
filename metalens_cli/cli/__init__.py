"""Click commands: one thin module per subcommand."""
