# `make demo` and `make test` create .venv with python3.12 and install the package on first use.
PYTHON312 := $(shell for candidate in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12 /usr/local/bin/python3.12; do \
	"$$candidate" --version >/dev/null 2>&1 && { echo "$$candidate"; break; }; done)
VENV := .venv
INSTALLED := $(VENV)/.installed

.PHONY: demo pseudo-demos eval-suite test install clean

install: $(INSTALLED)

$(INSTALLED): pyproject.toml
	@test -n "$(PYTHON312)" || { echo "error: python3.12 not found (LeRobot 0.6 needs Python 3.12)"; exit 1; }
	test -x $(VENV)/bin/python || $(PYTHON312) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -e '.[dev]'
	touch $(INSTALLED)

# Record 2 demonstrations of a bullet_tabletop task, evaluate the best available policy, print success + videos.
demo: $(INSTALLED)
	$(VENV)/bin/lerobot-ip-demo

pseudo-demos: $(INSTALLED)
	$(VENV)/bin/lerobot-ip-generate --config configs/generate/default.json --overwrite \
		--preview outputs/pseudo_demos_preview.png

POLICY ?= demo_replay
eval-suite: $(INSTALLED)
	$(VENV)/bin/lerobot-ip-eval-suite --policy $(POLICY) --episodes 10 --out outputs/eval_suite

# CI=true skips tests marked slow.
test: $(INSTALLED)
	$(VENV)/bin/python -m pytest -q $(if $(filter true,$(CI)),-m "not slow",)

clean:
	rm -rf outputs .pytest_cache
