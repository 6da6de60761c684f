"""The ``sc-fem`` command line (one ``cmd_*.py`` module per command, found automatically)."""
