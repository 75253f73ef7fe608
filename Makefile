# Two commands for a fresh machine: `make demo` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	mkdir -p out
	$(VENV)/bin/fd-send samples/grid_bbaf2n.mpg | $(VENV)/bin/fd-recv -o out/demo.mp4
	$(VENV)/bin/fd-enroll samples/grid_bbaf2n.mpg -o out/grid.fdface
	$(VENV)/bin/fd-send samples/grid_bbaf2n.mpg --face out/grid.fdface | $(VENV)/bin/fd-recv -o out/demo-picture.mp4
	$(VENV)/bin/fd-send samples/grid_bbaf2n.mpg --face out/grid.fdface --bitrate 10 | $(VENV)/bin/fd-recv -o out/demo-layer.mp4
	$(VENV)/bin/fd-send samples/grid_bbaf2n.mpg --face out/grid.fdface | $(VENV)/bin/fd-recv --look face -o out/demo-own-face.mp4
	$(VENV)/bin/fd-send samples/grid_bbaf2n.mpg --face out/grid.fdface --params paper --rule paper | $(VENV)/bin/fd-recv --look face -o out/demo-paper.mp4
	$(VENV)/bin/python docs/make_demo_picture.py --video out/demo-side-by-side.mp4
	@echo "wrote out/demo.mp4 (generic shaded face), out/demo-picture.mp4 (the speaker's whole picture: their"
	@echo "reference picture warped by their moving face model), out/demo-side-by-side.mp4 (original | whole"
	@echo "picture | shaded face), out/demo-layer.mp4 (the whole picture with the picture layer at 10 kbit/s),"
	@echo "out/demo-own-face.mp4 (their textured face alone, with their motion basis)"
	@echo "and out/demo-paper.mp4 (their face moved by the paper's model exactly: its 13 parameters and equations)"

test: $(STAMP)
	$(PY) -m pytest -q

# mypy checks the package as it installs (facedeform.codec, ...): build/typecheck/facedeform links to the folders.
lint: $(STAMP)
	$(PY) -m pip install -q -e '.[lint]'
	$(VENV)/bin/ruff check
	rm -rf build/typecheck && mkdir -p build/typecheck/facedeform
	ln -s $(CURDIR)/facedeform/*.py build/typecheck/facedeform/
	for d in codec common sender receiver protocol experiment; do ln -s $(CURDIR)/$$d build/typecheck/facedeform/$$d; done
	cd build/typecheck && $(CURDIR)/$(VENV)/bin/mypy --config-file $(CURDIR)/pyproject.toml -p facedeform

bench: $(STAMP)
	$(PY) benchmarks/bench_pipeline.py

clean:
	rm -rf $(VENV) out
