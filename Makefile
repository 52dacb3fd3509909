# Two commands on a fresh machine: `make demo` and `make test`. Both create .venv when missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck unit setup lock clean docs

$(STAMP): requirements.lock pyproject.toml
	@bash scripts/ensure-system-deps.sh
	@bash scripts/make-venv.sh $(PYTHON) $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	@touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/palpate demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/python scripts/typecheck.py

test: $(STAMP) lint typecheck
	$(BIN)/python -m pytest -q

docs: $(STAMP)
	$(BIN)/palpate docs messages -o docs/messages.md
	$(BIN)/palpate docs nodes -o docs/nodes.md

lock:
	$(BIN)/python -m pip freeze --exclude-editable | grep -v '^palpate' > requirements.lock

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
