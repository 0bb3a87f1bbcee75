"""Names, colours and columns of the evaluation report: the paper's method and stage labels and the
columns of ``metrics.csv`` / ``sweep.csv`` / ``options.csv``."""
from __future__ import annotations

from ..inference.pipeline import STAGES

#: method key -> label in tables and plots (the paper's names)
METHOD_LABELS = {
    "full": "Full ray cast",
    "recnn": "RecNN alone",
    "recnn_sparser": "RecNN alone, sparser pattern",
    "las": "LAS",
    "las_searched": "LAS at the promise (its IPR searched)",
    "las_equal": "LAS at equal quality (within 0.1 dB of IML/S)",
    "iml": "IML + RecNN",
    "imls": "IML/S + RecNN",
    "imls_fill": "IML/S mask + fill + RecNN",
    "imls_trained": "IML/S, its own decoder at its own point + RecNN",
    "blue_noise": "blue noise + decoder + RecNN",
    "two_pass": "two passes + fill + RecNN (no IMS)",
    "iml_selective": "IML IM, selectively rendered",
    # the same two methods timed on the other ray caster (the evaluation's both_ray_casters): the same pixels
    "recnn_skip": "RecNN alone, empty-space skipping",
    "recnn_noskip": "RecNN alone, every sample marched",
    "imls_skip": "IML/S + RecNN, empty-space skipping",
    "imls_noskip": "IML/S + RecNN, every sample marched",
}
#: the other ray caster's twins of the RecNN alone and IML/S: timed only, on the timed views (their images are the
#: main methods'); :func:`ray_caster_twin` names them
TWIN_METHODS = ("recnn_skip", "recnn_noskip", "imls_skip", "imls_noskip")
METHOD_ORDER = ("full", "recnn", "recnn_sparser", "las", "las_searched", "las_equal", "iml", "imls", "imls_fill", "imls_trained", "blue_noise",
                "two_pass", *TWIN_METHODS)


def ray_caster_twin(method: str, skip_empty: bool) -> str:
    """The key of ``method`` (``recnn`` or ``imls``) timed on the ray caster with ``skip_empty``.

    Example:
        >>> ray_caster_twin("recnn", False), ray_caster_twin("imls", True)
        ('recnn_noskip', 'imls_skip')
    """
    return f"{method}_{'skip' if skip_empty else 'noskip'}"
STAGE_LABELS = {
    "low_res_render": "low-res render",
    "render": "render",
    "importance": "importance",
    "selective_render": "selective render",
    "decoder": "decoder",
    "recnn": "RecNN",
}
# colours of the paper's time-breakdown figure: rendering blue/green, importance orange, RecNN red
STAGE_COLORS = {
    "low_res_render": "#1f77b4",
    "render": "#6baed6",
    "importance": "#ff7f0e",
    "selective_render": "#2ca02c",
    "decoder": "#9467bd",
    "recnn": "#d62728",
}
METHOD_COLORS = {"full": "#555555", "recnn": "#1f77b4", "recnn_sparser": "#17becf", "las": "#2ca02c", "las_searched": "#98df8a", "las_equal": "#c5e8b0", "iml": "#ff7f0e",
                 "imls": "#d62728", "iml_selective": "#9467bd", "imls_fill": "#8c564b", "imls_trained": "#e377c2",
                 "blue_noise": "#7f7f7f",
                 "two_pass": "#bcbd22", "recnn_skip": "#aec7e8", "recnn_noskip": "#aec7e8", "imls_skip": "#ff9896",
                 "imls_noskip": "#ff9896"}

#: columns of metrics.csv, in order
METRIC_COLUMNS = (
    ["view", "row", "method"]
    + [f"{s}_ms" for s in STAGES]
    + ["total_ms", "ipr", "c_share", "rendered_pixels", "psnr", "ssim"]
)
SWEEP_COLUMNS = ["view", "row", "method", "setting", "value"] + METRIC_COLUMNS[3:]
#: columns of options.csv (IML/S network stages under each inference option, mean over views)
OPTION_COLUMNS = ["option", "first_call_s", "importance_ms", "selective_render_ms", "decoder_ms", "recnn_ms",
                  "networks_ms", "total_ms", "psnr", "error"]


MASK_LABELS = {"ims": "IMS (from the view)", "iml": "IML (from the C-Image)", "blue_noise": "blue noise (untrained)"}
