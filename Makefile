# vmehil: two commands do all the set-up on a fresh machine (Python >= 3.11 and make):
#   make run    build .venv from pyproject.toml and run the main job on the embedded default
#   make test   build .venv and run ruff, the import contracts (lint-imports), mypy and the test suite
#               (make test-fast: the same without the slow tests)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: run test test-fast lint venv tools constraints bench clean reproduce mutation

venv: $(STAMP) tools

# System tools some tests drive (socat: a terminal program on the console's pty; libfuse 3: the
# FUSE stand-in for /dev/bus/vme). Installed when
# missing and possible (root with apt-get, as on CI); elsewhere those tests skip, saying why.
tools:
	@command -v socat >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
		{ apt-get install -y -qq socat >/dev/null 2>&1 || \
		  { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq socat >/dev/null 2>&1; }; }; } || \
		echo "socat not installed and not installable here (root and apt-get): its console test will skip"
	@{ command -v fusermount3 >/dev/null 2>&1 && ldconfig -p | grep -q libfuse3.so.3; } || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
		{ apt-get install -y -qq fuse3 libfuse3-3 >/dev/null 2>&1 || \
		  { apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq fuse3 libfuse3-3 >/dev/null 2>&1; }; }; } || \
		echo "libfuse 3 not installed and not installable here: the vme_user FUSE tests will skip"

# Every extra and the test tools, at the versions in constraints.txt (what CI ran).
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[all,test]'
	touch $(STAMP)

# Refresh constraints.txt: what a fresh venv resolves today from pyproject.toml (then run make test
# and commit both). tqdm and import-linter are named until pyproject.toml lists them.
CVENV := .venv-constraints
constraints:
	rm -rf $(CVENV)
	$(PYTHON) -m venv $(CVENV)
	$(CVENV)/bin/python -m pip install --quiet --upgrade pip
	$(CVENV)/bin/python -m pip install --quiet -e '.[all,test]' tqdm import-linter
	{ echo "# What a fresh venv resolved from pyproject.toml (make constraints); make venv installs with -c this."; \
	  $(CVENV)/bin/python -m pip freeze --exclude-editable; } > constraints.txt
	rm -rf $(CVENV)

run: $(STAMP)
	$(VENV)/bin/vmehil run --report reports/run --json reports/run/run.json
	@echo ""
	@echo "Next:"
	@echo "  $(VENV)/bin/vmehil calibrate all --auto    calibrate the ADCs, DACs, encoders, amplifiers and pots, then run again"
	@echo "  $(VENV)/bin/vmehil reproduce               the JPL paper's figures against their bands (docs/jpl-figures.md)"
	@echo "  $(VENV)/bin/vmehil tune bode               the loop's margins; tune limit-cycle, tune sweep (docs/tuning.md)"
	@echo "  $(VENV)/bin/vmehil --help                  every command"

# The README's "What it reproduces" table, re-run in a temporary directory and compared with the
# paper's bands (exit 1 when a figure leaves its band): docs/jpl-figures.md. RIG=NAME|PATH runs
# it on another rig (make reproduce RIG=jpl-arm-vmic); a slow check, not part of make test.
reproduce: $(STAMP)
	$(VENV)/bin/vmehil reproduce $(if $(RIG),--rig $(RIG))

lint: $(STAMP)
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports --no-logo
	$(PY) -m mypy

# The tests run inside a private network namespace with only loopback (and the IPv4 multicast
# range routed over it) when `unshare -n` works (root, CI): the udp_multicast CAN tests then run
# without any traffic leaving the host. Elsewhere pytest runs plainly and those tests skip.
NETNS := unshare -n sh -c 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec "$$0" "$$@"'

# mypy (the slowest of the three checks: ~25-40 s from a clean clone, no cache) runs beside pytest,
# and its report is printed after pytest's; ruff and the import walls (a second each) run first.
# pytest itself runs as two processes, one per core (tests/pair.py: the tests that use ports or
# the CAN multicast groups in one, the rest in the other). The recipe fails when either fails.
MYPY_LOG := $(VENV)/mypy-test.log

test: $(STAMP) tools
	$(PY) -m ruff check .
	$(VENV)/bin/lint-imports --no-logo
	@echo "$(PY) -m mypy  (beside pytest: its report follows pytest's)"; \
	$(PY) -m mypy > $(MYPY_LOG) 2>&1 & types_pid=$$!; \
	if unshare -n true 2>/dev/null && command -v ip >/dev/null; then \
		echo "pytest in a private network namespace (loopback only), as two processes (tests/pair.py)"; \
		$(NETNS) $(PY) -m tests.pair -q $(PYTEST_ARGS); \
	else \
		$(PY) -m tests.pair -q $(PYTEST_ARGS); \
	fi; tests=$$?; \
	wait $$types_pid; types=$$?; echo "mypy:"; cat $(MYPY_LOG); rm -f $(MYPY_LOG); \
	[ $$tests -ne 0 ] && exit $$tests; exit $$types

# The same without the tests marked slow (over 1.5 s each on the 2-core machine at rest): the
# documented fast subset for the edit-test cycle (goal: under 3 min on 2 cores); CI runs `test`.
test-fast: PYTEST_ARGS = -m "not slow"
test-fast: test

bench: $(STAMP)
	$(PY) -m benchmarks

# Mutation testing (docs/mutation.md; not part of make test or CI: hours for every module). mutmut
# ([tool.mutmut] in pyproject.toml) mutates hal's drivers, register maps and conversions and
# servo/control/law.py and runs the fast tests that reach each mutant. Resumable: the results stay
# in mutants/, a second run checks only what is not checked yet (delete mutants/ to start afresh).
# MUTATE narrows it to mutant names (globs): make mutation MUTATE='hal.quadrature.*'.
# MUTATION_JOBS: mutants run in parallel (default 2, the reference machine's cores).
MUTATE ?=
MUTATION_JOBS ?= 2
mutation: $(STAMP)
	@start=$$(date +%s); \
	$(VENV)/bin/mutmut run --max-children $(MUTATION_JOBS) $(MUTATE); status=$$?; \
	$(PY) -m tests.mutation_report mutants; \
	echo "make mutation: $$(( $$(date +%s) - start )) s elapsed (exit $$status)"; exit $$status

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis .import_linter_cache
