"""``vmehil`` subcommands, one module each."""
