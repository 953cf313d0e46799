# `make demo`, `make test`, `make bench`: each installs what is missing first (scripts/setup.sh).
PY := .venv/bin/python

.PHONY: setup demo test bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) -m mscloth demo --out out

test:
	@bash scripts/setup.sh test
	$(PY) -m pytest -q -n auto --dist loadfile

bench: setup
	$(PY) bench/benchmark.py --out bench/RESULTS.md
	$(PY) bench/footprint_estimator.py --set resolution=128 --out bench/RESULTS.md
	$(PY) bench/first_picture.py --out bench/RESULTS.md

clean:
	rm -rf out .pytest_cache
