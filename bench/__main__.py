import sys

from bench.cli import program

sys.exit(program())
