"""The paper's Table 2, as printed, for tests and the comparison script."""
import csv
from pathlib import Path

TABLE2_CSV = Path(__file__).resolve().parent / 'data' / 'paper_table2.csv'


def _number(text):
    return float(text) if text.strip() else None


def load_table2():
    """Rows of Table 2 as dicts (numbers as floats, missing cells as None)."""
    with open(TABLE2_CSV, newline='') as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith('#')))
    return [{k: (v if k == 'camera' else _number(v)) for k, v in row.items()} for row in rows]
