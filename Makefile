# Two entry points for a fresh machine (see README):
#   make demo   install into .venv, then build the embedded demo dataset offline
#   make test   install into .venv, then run the test suite
VENV   ?= .venv
PYTHON ?= python3
BIN    := $(VENV)/bin

.PHONY: demo test test-slow bench docs-figures clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch/torchvision pinned to the releases this project is tested with (CPU or CUDA alike)
	$(BIN)/pip install --quiet -e '.[test,train,bench]' torch==2.14.1 torchvision==0.29.1
	touch $@

demo: $(VENV)/.installed
	$(BIN)/osmseg demo --out demo-out

test: $(VENV)/.installed
	$(BIN)/lint-imports
	$(BIN)/ruff check .
	# the type checker runs beside the tests (its cold start is half a minute of one core, and the
	# tests leave a core idle while they wait on the processes they start), its report printed after
	# theirs; either failing fails the target. The tests: one process per core, an idle one taking
	# queued tests from a busy one (worksteal: the long end-to-end tests do not leave a core waiting
	# at the end), and the 20 slowest named
	@report=$$(mktemp); echo "$(BIN)/mypy (beside the tests; its report follows theirs)"; \
	$(BIN)/mypy >"$$report" 2>&1 & checker=$$!; \
	$(BIN)/pytest -q -n auto --dist worksteal --durations=20; tests=$$?; \
	wait $$checker; types=$$?; echo "$(BIN)/mypy:"; cat "$$report"; rm -f "$$report"; \
	[ $$tests -eq 0 ] && [ $$types -eq 0 ]

# the long end-to-end cases make test leaves out (CI runs both): learning to a bar, two trainings for
# RGB localization, the docs' cheap figures measured again, benchmarks on real data
test-slow: $(VENV)/.installed
	$(BIN)/pytest -q -m slow -n auto --dist worksteal --durations=20

bench: $(VENV)/.installed
	$(BIN)/python benchmarks/bench_build.py

# every figure README.md and docs/*.md quote from a command, measured again and written in
# (minutes; PAIRS=DIR: the authors' annotated pairs, github.com/sebagreen/landmark-graph-matching)
docs-figures: $(VENV)/.installed
	$(BIN)/python docs/figures.py $(if $(PAIRS),--pairs $(PAIRS))

clean:
	rm -rf demo-out .pytest_cache
