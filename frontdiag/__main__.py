from frontdiag.cli import run

run()
