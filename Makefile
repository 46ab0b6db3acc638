# Shorthands for the README's two commands, where make is installed (the scripts themselves need only bash).
.PHONY: setup demo test

setup:
	bash scripts/setup.sh

demo:
	bash scripts/demo.sh

test:
	bash scripts/test.sh
