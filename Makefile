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

# onnxruntime-web for the page that needs no server (`walkdiff play --static`, `walkdiff export --format
# web`): the npm package at a pinned version, checked against its registry integrity (sha512).
ORT_WEB := .cache/onnxruntime-web-1.30.0
ORT_WEB_URL := https://registry.npmjs.org/onnxruntime-web/-/onnxruntime-web-1.30.0.tgz
ORT_WEB_SHA512 := q0y+JrrtukXSzsBWEMccVfqX25LRmosXHF+CaRJmg8pZClzcV7svNc4rKY3jL02Vb7QmRMDs1SigqR4CXAfKYQ==

install: $(STAMP) web

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
$(ORT_WEB)/ort.wasm.min.js: | $(STAMP)
	@mkdir -p $(ORT_WEB)/npm
	$(PY) -c "import urllib.request as u, sys; u.urlretrieve(sys.argv[1], sys.argv[2])" $(ORT_WEB_URL) $(ORT_WEB)/npm/ort-web.tgz
	@$(PY) -c "import base64, hashlib, sys; d = base64.b64encode(hashlib.sha512(open(sys.argv[1], 'rb').read()).digest()).decode(); sys.exit(0 if d == sys.argv[2] else 'onnxruntime-web: the download does not match its pinned sha512 (' + d + ')')" $(ORT_WEB)/npm/ort-web.tgz $(ORT_WEB_SHA512)
	tar -xzf $(ORT_WEB)/npm/ort-web.tgz -C $(ORT_WEB) --strip-components=2 \
	  package/dist/ort.wasm.min.js package/dist/ort-wasm-simd-threaded.wasm package/dist/ort-wasm-simd-threaded.mjs
	@rm -rf $(ORT_WEB)/npm

lint: install
	$(VENV)/bin/ruff check walkdiff tests
	$(VENV)/bin/ruff format --check walkdiff tests

clean:
	rm -rf $(VENV) .cache .pytest_cache .ruff_cache *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
