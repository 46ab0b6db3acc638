"""`python -m servofmu`: the `servofmu` command."""
from .cli import run

run()
