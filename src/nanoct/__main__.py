"""``python -m nanoct`` runs the command-line interface."""

from .cli import main

main()
