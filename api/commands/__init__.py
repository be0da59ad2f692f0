"""One module per ``iblbench`` command, each with ``add_parser(subparsers)`` and ``run(args)``;
the flags several commands share are in :mod:`.common`."""
