"""imls_lightning.orp.report: orp.yaml data and the sweeper's table, from a real search."""
from __future__ import annotations

import yaml

from imls_lightning import orp


def _report(gap):
    settings = orp.ORPSettings.from_mapping({"epsilon_db": 1.0, "tolerance": 0.25}, prefix="sweeper.")

    def job(u: float) -> dict:
        return {"status": "ok", "gap_db": gap(u), "c_share": u, "ipr": u / 4,
                "psnr_db": {"iml_recnn": 30 - gap(u), "recnn": 30.0}, "iml_checkpoint": f"/runs/iml-{u}.ckpt"}

    result = settings.search().run(orp.batched(job))
    return orp.orp_report(result, settings, context={"scene": "tiny"}), result


def test_smoke_report_of_a_found_orp_is_plain_yaml():
    report, result = _report(lambda u: 4.0 * (0.5 - u) if u < 0.5 else 0.0)
    assert report["found"] and report["orp"]["mean"] == result.mean and report["gap_db"] <= 1.0
    assert report["orp"]["c_share"] == round(result.best.u, 4) and report["context"] == {"scene": "tiny"}
    assert len(report["jobs"]) == result.jobs and all(j["status"] == "ok" for j in report["jobs"])
    assert yaml.safe_load(yaml.safe_dump(report)) == report  # plain data, no numpy or OmegaConf types
    table = orp.format_table(report)
    assert f"{result.mean:.4f}"[:5] in table and len(table.splitlines()) >= len(report["jobs"])


def test_report_when_no_mean_meets_epsilon():
    report, _ = _report(lambda u: 5.0)
    assert not report["found"] and report["orp"] is None and report["psnr_db"] is None
    assert all(not j["meets_epsilon"] for j in report["jobs"])
