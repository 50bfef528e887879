# walkdiff: every target installs first when needed, so a fresh clone needs one command.
VENV     ?= .venv
PY       := $(VENV)/bin/python
STAMP    := $(VENV)/.installed
LOCK     := conf/constraints.txt
CONFIG   ?=
MLFLOW_DB := sqlite:///mlruns/mlflow.db
UI_PORT  ?= 5000

EVALUATOR := checkpoints/evaluator_xia/last.ckpt

.PHONY: install test docs-check train evaluator ui lint clean web

# onnxruntime-web for the page that needs no server (`walkdiff export --format web`), pinned, from npm.
ORT_WEB := .cache/onnxruntime-web-1.30.0

install: $(STAMP)

# Exact pins in $(LOCK); torch is the CPU build pinned in DESIGN.md. Re-runs only when they change.
$(STAMP): pyproject.toml $(LOCK)
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -c $(LOCK) -e '.[dev]'
	@touch $(STAMP)
	@echo "installed: run \`source $(VENV)/bin/activate\` to put walkdiff on your PATH (or call $(VENV)/bin/walkdiff)"

test: install
	$(PY) -m pytest -q

# Every command and link in README.md and docs/*.md against the real parser, configs, Makefile and files.
docs-check: install
	$(PY) -m pytest -q tests/test_docs.py

# The motion evaluator (style + content classifier) that training metrics and `walkdiff evaluate` use.
evaluator: $(EVALUATOR)
$(EVALUATOR): | install
	$(VENV)/bin/walkdiff fit --config conf/evaluator_xia.yaml

# The paper's GPU setting where a GPU is present, the 2-core CPU setting where not (override: CONFIG=...).
train: install $(EVALUATOR)
	@cfg="$(CONFIG)"; \
	if [ -z "$$cfg" ]; then \
	  if $(PY) -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"; then \
	    cfg=conf/xia.yaml; echo "GPU found: training with $$cfg"; \
	  else cfg=conf/xia_cpu.yaml; echo "No GPU: training with $$cfg (CPU setting)"; fi; \
	fi; \
	$(VENV)/bin/walkdiff fit --config $$cfg

# Prints each experiment's run list first: MLflow 3.17 opens experiments on its GenAI pages unless told.
ui: install
	@$(PY) -c "from walkdiff.common.tracking import print_ui_addresses as p; p('$(MLFLOW_DB)', 'http://127.0.0.1:$(UI_PORT)')"
	MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false $(VENV)/bin/mlflow server \
	  --backend-store-uri $(MLFLOW_DB) --default-artifact-root ./mlruns/artifacts \
	  --host 127.0.0.1 --port $(UI_PORT) --workers 1

web: $(ORT_WEB)/ort.wasm.min.js
$(ORT_WEB)/ort.wasm.min.js:
	@mkdir -p $(ORT_WEB)/npm
	cd $(ORT_WEB)/npm && npm pack --silent onnxruntime-web@1.30.0
	tar -xzf $(ORT_WEB)/npm/onnxruntime-web-1.30.0.tgz -C $(ORT_WEB) --strip-components=2 \
	  package/dist/ort.wasm.min.js package/dist/ort-wasm-simd-threaded.wasm package/dist/ort-wasm-simd-threaded.mjs
	@rm -rf $(ORT_WEB)/npm

lint: install
	$(VENV)/bin/ruff check walkdiff tests
	$(VENV)/bin/ruff format --check walkdiff tests

clean:
	rm -rf $(VENV) .cache .pytest_cache .ruff_cache *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
