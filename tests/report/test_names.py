"""imls_lightning.report.names: every method and stage has one label and one colour."""
from __future__ import annotations

from imls_lightning.inference.pipeline import STAGES
from imls_lightning.report import names


def test_every_method_and_stage_is_named_and_coloured():
    assert set(names.METHOD_ORDER) <= set(names.METHOD_LABELS)
    assert set(names.METHOD_ORDER) <= set(names.METHOD_COLORS)
    assert set(STAGES) <= set(names.STAGE_LABELS) and set(STAGES) <= set(names.STAGE_COLORS)
    assert len(set(names.METHOD_LABELS.values())) == len(names.METHOD_LABELS)  # labels tell methods apart


def test_csv_columns_have_no_duplicates():
    for cols in (names.METRIC_COLUMNS, names.SWEEP_COLUMNS, names.OPTION_COLUMNS):
        assert len(set(cols)) == len(cols)
