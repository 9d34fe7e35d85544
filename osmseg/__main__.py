"""``python -m osmseg`` (and ``torchrun -m osmseg``) runs the command line."""

from osmseg.cli.launch import main

main()
