"""The operator's side of a running launch: its XML-RPC API, the run's token, /diagnostics, and the `launcher` subcommands that use them."""
