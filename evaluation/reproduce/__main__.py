"""`python -m evaluation.reproduce` (`make reproduce`): see evaluation/reproduce/cli.py."""

import sys

from evaluation.reproduce.cli import main

sys.exit(main(sys.argv[1:]))
