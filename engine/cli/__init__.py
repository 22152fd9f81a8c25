"""The ``vgr`` command: :mod:`engine.cli.main` builds the parser and dispatches, one module per verb
family, :mod:`engine.cli.exit_codes` holds the one exit-code table of every verb. Plugins add verbs
through the ``vgr_cli_verbs`` hook (engine.hookspecs), not by module names here."""
