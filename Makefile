# The two commands of the README: `make demo` and `make test` (each sets everything up first).
.PHONY: setup demo test

setup:
	bash scripts/setup.sh

demo: setup
	.venv/bin/servofmu demo

test: setup
	bash scripts/test.sh
