"""Each coefficient encoding (Baking Lab's set) against quadrature on analytic radiance fields:
bench/results/encodings_basis.md. Core only.

    .venv/bin/python bench/encodings_basis.py

For each field of tests/encoding_fields.py (a narrow lobe, a sky gradient, two directional
lights, over the hemisphere of n_v), its L2 SH (the traced data) is encoded by every basis and
solve; the table gives the relative RMS error, against the field's own quadrature, of the
irradiance at 5 shading normals and of the GGX specular (F0 = 1) at α = 0.25, 0.5, 0.75 (one
view 40° from each normal). "L2 SH (ref)" is the error of the traced L2 SH itself.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from hhd_lightmapper.core.encoding import EncoderSettings, registry

ROOT = Path(__file__).resolve().parents[1]


def _test_helper(name: str):
    """tests/<name>.py as module `name` (the fields and quadrature the tests use)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


_test_helper("quadrature")
_fields = _test_helper("encoding_fields")
N_V, fields, normals, relative_rms, views = (
    _fields.N_V,
    _fields.fields,
    _fields.normals,
    _fields.relative_rms,
    _fields.views,
)

ALPHAS = (0.25, 0.5, 0.75)
ROWS = [("sh_l1", None), ("sh_l2", None), ("hl2", None), ("hbasis_l1", None), ("hbasis_l2", None)] + [
    (f"sg{k}", s) for k in (5, 6, 9, 12) for s in ("adhoc", "ls", "nnls")
]
FLOATS = {
    "sh_l1": 12,
    "sh_l2": 27,
    "hl2": 9,
    "hbasis_l1": 12,
    "hbasis_l2": 18,
    "sg5": 15,
    "sg6": 18,
    "sg9": 27,
    "sg12": 36,
}


def measure() -> dict:
    n = normals()
    v = views(n)
    n_v = np.broadcast_to(N_V, n.shape)
    out = {}
    for field in fields():
        s = np.broadcast_to(field.sh(), (len(n), 9, 3))
        i_ref = field.irradiance(n)
        s_ref = {a: field.specular(n, v, a) for a in ALPHAS}
        for model, solve in ROWS:
            b = registry.basis_of(EncoderSettings(model=model, solve=solve or "nnls"))
            c = b.coefficients(s, n_v)
            row = [relative_rms(b.irradiance(c, n_v, n), i_ref)]
            row += [relative_rms(b.specular(c, n_v, n, v, a), s_ref[a]) if b.SPECULAR else None for a in ALPHAS]
            out[(field.name, model, solve)] = row
    return out


def _cell(x) -> str:
    return "—" if x is None else f"{x:.3f}"


def table(results: dict) -> str:
    lines = [
        "# Coefficient encodings against quadrature on analytic fields",
        "",
        "`bench/encodings_basis.py`: relative RMS error (over 5 shading normals in n_v's hemisphere, RGB) of each",
        "encoding's reconstruction from the field's L2 radiance SH, against the field's own quadrature",
        "(tests/encoding_fields.py). Specular: GGX with F0 = 1, α = GGX α (Baking Lab's roughness; Blender",
        "Roughness R gives α = R²), one view 40° from each normal. — : the basis has no specular.",
        "SG solves fit the radiance reconstructed from the L2 SH at 256 hemisphere directions",
        "(core/encoding/sg.py), so they cannot hold more than L2 does.",
        "",
    ]
    for field in dict.fromkeys(k[0] for k in results):
        lines += [
            f"## {field}",
            "",
            "| encoding | floats/texel | irradiance | spec α=0.25 | spec α=0.5 | spec α=0.75 |",
            "|---|---|---|---|---|---|",
        ]
        for model, solve in ROWS:
            row = results[(field, model, solve)]
            name = model + (f" ({solve})" if solve else "")
            lines.append(f"| {name} | {FLOATS[model]} | " + " | ".join(_cell(x) for x in row) + " |")
        lines.append("")
    lines += ["## SG9 vs L2 SH specular at α = 0.25 (the paper's claim)", ""]
    lines += ["| field | L2 SH | SG9 adhoc | SG9 ls | SG9 nnls |", "|---|---|---|---|---|"]
    for field in dict.fromkeys(k[0] for k in results):
        cells = [results[(field, "sh_l2", None)][1]] + [results[(field, "sg9", s)][1] for s in ("adhoc", "ls", "nnls")]
        lines.append(f"| {field} | " + " | ".join(_cell(x) for x in cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    text = table(measure())
    path = ROOT / "bench" / "results" / "encodings_basis.md"
    path.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
