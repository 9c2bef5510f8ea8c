"""The subcommands of `micam`, one module each, each with `register(subparsers)`."""
