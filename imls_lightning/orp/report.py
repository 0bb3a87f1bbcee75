"""The ORP sweep's report: :func:`orp_report` (the data of ``orp.yaml``, :data:`REPORT_FILE`) and
:func:`format_table` (the text table the sweeper prints)."""
from __future__ import annotations

import math
from typing import Any, Mapping

from .search import ORPResult, ORPSettings

REPORT_FILE = "orp.yaml"


def _r(x: Any, nd: int = 4) -> Any:
    return round(float(x), nd) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(float(x)) else x


def orp_report(result: ORPResult, settings: ORPSettings, *, job_dirs: Mapping[int, str] | None = None,
               context: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``orp.yaml`` data: the ORP at the chosen mean value, its PSNRs, gap and latencies,
    every job tried, the search's progress and the settings (plain data).

    ``job_dirs`` maps the index of an evaluation (in ``result.evaluations``) to its job directory
    when the record does not carry it (failed jobs).
    """
    job_dirs = dict(job_dirs or {})
    best = result.best
    rec = best.record if best is not None else {}
    jobs = []
    for i, e in enumerate(result.evaluations):
        r = e.record
        jobs.append({
            "job": i, "round": e.round, "mean": e.u, "status": e.status,
            "meets_epsilon": e.meets(result.epsilon_db), "gap_db": _r(e.gap_db),
            "psnr_db": {k: _r(v) for k, v in (r.get("psnr_db") or {}).items()} or None,
            "ipr": _r(r.get("ipr")), "c_share": _r(r.get("c_share")),
            "imls_ipr": _r(r.get("imls_ipr")), "imls_c_share": _r(r.get("imls_c_share")),
            "job_dir": r.get("job_dir") or job_dirs.get(i), "iml_checkpoint": r.get("iml_checkpoint"),
            "ims_checkpoint": r.get("ims_checkpoint"), "minutes": r.get("minutes"), "error": e.error,
        })
    orp = None
    if best is not None:
        # the paper's ORP is the share of the C-Image rendered; the IPR is the share of the FR-Image
        orp = {"c_share": _r(rec.get("imls_c_share") if settings.gap_of == "imls" else rec.get("c_share")),
               "ipr": _r(rec.get("imls_ipr") if settings.gap_of == "imls" else rec.get("ipr")),
               "mean": best.u, "gap_of": settings.gap_of}
    return {
        "orp": orp,
        "found": result.found,
        "mean": result.mean,
        "epsilon_db": result.epsilon_db,
        "gap_db": _r(best.gap_db) if best is not None else None,
        "psnr_db": {k: _r(v) for k, v in (rec.get("psnr_db") or {}).items()} if best is not None else None,
        "latency_ms": rec.get("latency_ms") if best is not None else None,
        "iml_checkpoint": rec.get("iml_checkpoint"),
        "ims_checkpoint": rec.get("ims_checkpoint"),
        "recnn_checkpoint": rec.get("recnn_checkpoint"),
        "search": {"rounds": result.rounds, "jobs": result.jobs, "stop_reason": result.stop_reason,
                   "bracket_final": [result.bracket[0], result.bracket[1]], "non_monotone": result.non_monotone},
        "settings": settings.as_dict(),
        **({"context": dict(context)} if context else {}),
        "jobs": jobs,
    }


def format_table(report: Mapping[str, Any]) -> str:
    """A short text table of the jobs tried and the ORP found.

    Example:
        >>> from imls_lightning.orp.search import ORPSettings, batched
        >>> settings = ORPSettings.from_mapping({"max_rounds": 2})
        >>> result = settings.search().run(batched(lambda u: {"gap_db": 0.5 if u > 0.05 else 2.0,
        ...                                                    "c_share": 0.3, "ipr": 0.1}))
        >>> print(format_table(orp_report(result, settings)))
        job round      mean status   gap dB  IML+RecNN    RecNN    IML/S  C-share     IPR  ok
          0     1       0.1     ok    0.500          -        -        -    0.300   0.100  yes
          1     2  0.031623     ok    2.000          -        -        -    0.300   0.100  no
        ORP: 30.0% of the C-Image (IPR 10.00%) at model.mean=0.1, gap 0.500 dB <= 1.0 dB
        (2 jobs in 2 rounds; stopped: max_rounds)
    """

    def f(x: Any, spec: str) -> str:
        return format(x, spec) if isinstance(x, (int, float)) and not isinstance(x, bool) else "-"

    lines = [f"{'job':>3} {'round':>5} {'mean':>9} {'status':>6} {'gap dB':>8} {'IML+RecNN':>10} {'RecNN':>8} {'IML/S':>8} {'C-share':>8} {'IPR':>7}  ok"]
    for j in report["jobs"]:
        p = j.get("psnr_db") or {}
        lines.append(
            f"{j['job']:>3} {j['round']:>5} {j['mean']:>9.5g} {j['status']:>6} {f(j['gap_db'], '8.3f'):>8} "
            f"{f(p.get('iml_recnn'), '10.2f'):>10} {f(p.get('recnn'), '8.2f'):>8} {f(p.get('imls_recnn'), '8.2f'):>8} "
            f"{f(j['c_share'], '8.3f'):>8} {f(j['ipr'], '7.3f'):>7}  {'yes' if j['meets_epsilon'] else 'no'}"
            + (f"   ({j['error'][:80]})" if j.get("error") else "")
        )
    s = report["search"]
    if report["orp"]:
        o = report["orp"]
        lat = report.get("latency_ms") or {}
        speed = lat.get("speedup_vs_recnn")
        share = f"{100 * o['c_share']:.1f}% of the C-Image" if isinstance(o["c_share"], (int, float)) else "?"
        ipr = f"IPR {100 * o['ipr']:.2f}%" if isinstance(o["ipr"], (int, float)) else "IPR ?"
        lines.append(f"ORP: {share} ({ipr}) at {report['settings']['param']}={o['mean']:.5g}, "
                     f"gap {report['gap_db']:.3f} dB <= {report['epsilon_db']} dB"
                     + (f", selective-render speed-up x{speed:.2f}" if isinstance(speed, (int, float)) else ""))
    else:
        lines.append(f"ORP: none - no mean value in {report['settings']['bracket']} kept the gap within {report['epsilon_db']} dB")
    lines.append(f"({s['jobs']} jobs in {s['rounds']} rounds; stopped: {s['stop_reason']}"
                 + ("; gap(u) was not monotone" if s["non_monotone"] else "") + ")")
    return "\n".join(lines)
