# vmehil: two commands do all the set-up on a fresh machine (Python >= 3.11 and make):
#   make run    build .venv from pyproject.toml and run the main job on the embedded default
#   make test   build .venv and run ruff, the import contracts (lint-imports) and the test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: run test lint venv bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/vmehil run --report reports/run --json reports/run/run.json

lint: $(STAMP)
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports --no-logo

# The tests run inside a private network namespace with only loopback (and the IPv4 multicast
# range routed over it) when `unshare -n` works (root, CI): the udp_multicast CAN tests then run
# without any traffic leaving the host. Elsewhere pytest runs plainly and those tests skip.
NETNS := unshare -n sh -c 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec "$$0" "$$@"'

test: $(STAMP)
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports --no-logo
	@if unshare -n true 2>/dev/null && command -v ip >/dev/null; then \
		echo "pytest in a private network namespace (loopback only)"; \
		$(NETNS) $(PY) -m pytest -q; \
	else \
		$(PY) -m pytest -q; \
	fi

bench: $(STAMP)
	$(PY) -m benchmarks

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis .import_linter_cache
