"""One module per `usb2rc` subcommand: `add_parser(subparsers)` and `run(args) -> int`."""
