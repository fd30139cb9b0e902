"""`python -m receiver.cli` = `occloc`."""

from receiver.cli import console

console()
