"""``python -m samii``: the ``samii`` program."""

from samii.cli import program

program()
