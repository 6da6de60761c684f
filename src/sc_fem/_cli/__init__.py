"""The ``sc-fem`` command line: :data:`.main.COMMANDS` lists its command modules."""
