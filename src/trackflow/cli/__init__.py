"""Command line: ``trackflow <command>``; see ``trackflow.cli.main``."""
