"""One module per ``vislam`` subcommand; each defines ``add_arguments(parser)`` and ``run(args)``."""
