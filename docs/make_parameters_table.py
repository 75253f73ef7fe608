"""Write docs/parameters.md, the registry of the parameters (common/parameters.py) as tables; run from anywhere:
    .venv/bin/python docs/make_parameters_table.py
"""

from pathlib import Path

from facedeform.common.parameters import table

if __name__ == "__main__":
    (Path(__file__).parent / "parameters.md").write_text(table())
