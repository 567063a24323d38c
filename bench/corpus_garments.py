"""The corpus bench, garments: every garment of ../shared/corpus through pbc's garment door, as a user runs it.

    python bench/corpus_garments.py [--fit] [--samples 12] [--epochs 5] [--only GLOB] [--work DIR] [--out DIR]

One row per corpus garment (MakeHuman outfits piece by piece, DiffAvatar's meshes, a hospital gown, as their tools
wrote them), each through the commands a user types:

- ``pbc garment inspect FILE body=anny --out``: placed (the unit it found, the median distance to the rest body, its
  height against the body's stature, how far round the torso it reaches) or refused, with the refusal's line;
- ``pbc garment fit FILE --until checks``: every check before a drape passed, or the refusal's line;
- with ``--fit``, for each garment that passes the checks: ``pbc garment fit FILE --samples N --epochs E``, the
  drapes kept of asked, the minutes, the test error beside the training mean shape's.

Each garment's verdict: **right** (placed in the unit its source states, or fitted by its own binding: MakeHuman),
**refused** (one line naming the problem and a fix), or **wrong** (placed where its source says it cannot be: a
unit other than the stated one, a garment made for no body placed on one). Targets: every garment
placed right or refused with a fix; at least 80% of drapes kept on every garment that passes the checks; 0 placed
wrong without a word. Work goes to --work (resumable: a garment whose row is there is not run again); prints a
table and, as its last line, one JSON object of the figures with the device.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CORPUS = ROOT.parent / "shared" / "corpus"
TARGETS = {"kept": 0.80, "wrong": 0}

# what the corpus README states of each non-MakeHuman garment: its unit (None: unknown there, not judged) or "not on
# a body" (a garment made for no body: refused is right); the tests read the same file
STATED = yaml.safe_load((ROOT / "tests" / "data" / "corpus_garments.yaml").read_text())
PLACED = re.compile(r"placement \((\w+)\): (?:unit (.+?) \(|kept as given)")
ERROR = re.compile(r"^pbc garment: error: (.*)$", re.M)
PIECES = re.compile(r"garment\.piece=(\w+)")
# a setting a refusal names as its fix (garment.uvs=unwrap, garment.split_nonmanifold=true, ...)
FIX = re.compile(r"\b(garment\.(?:uvs|split_nonmanifold|position_unit|charts|made_on_rest)=[^\s,;)]+)")


def pbc(*args: str, timeout: float = 3600) -> tuple[int, str, float]:
    """Run `pbc ARGS` as a user does: (exit code, stdout + stderr, seconds)."""
    t0 = time.time()
    r = subprocess.run([sys.executable, "-m", "pbc", *args], capture_output=True, text=True, timeout=timeout,
                       cwd=ROOT)
    return r.returncode, r.stdout + r.stderr, time.time() - t0


def error_line(text: str) -> str | None:
    found = ERROR.findall(text)
    return found[-1] if found else None


def cases(corpus: Path) -> list[tuple[str, Path, list[str]]]:
    """(name, file, overrides) per garment file: the MakeHuman outfits (`.mhclo`, split into their pieces by `main`)
    and every other garment OBJ."""
    out = []
    garments = corpus / "garments"
    for mhclo in sorted(garments.rglob("*.mhclo")):
        out.append((mhclo.stem, mhclo, []))
    for obj in sorted(garments.rglob("*.obj")):
        if (obj.with_suffix(".mhclo")).is_file():
            continue
        out.append((str(obj.relative_to(garments)), obj, ["body=anny"]))  # on Anny, as MakeHuman's clothes
    return out


def outfit_places(path: Path, work: Path) -> list[str]:
    """The places of an outfit's pieces (top, bottom, ...) as `pbc garment inspect` names them when it refuses the
    outfit whole; [] for a garment of one piece."""
    rc, text, _ = pbc("garment", "inspect", str(path), "--out", str(work / "probe"))
    line = error_line(text) or ""
    return sorted(set(PIECES.findall(line)) - {"all"}) if "an outfit of" in line else []


def placement_figures(fitted: Path, body) -> dict:
    """The placed garment (fitted.obj, metres) against the rest body: median distance, height over stature, torso
    cover in degrees."""
    from pbc.geometry.garment.placement import _landmarks, _sdf, torso_cover_deg
    from pbc.geometry.meshio import read_obj

    mesh = read_obj(fitted, "placed garment", require_uv=False)
    p = mesh.vertices
    lm = _landmarks(body)
    stature = float(body.vertices[:, 1].max() - body.vertices[:, 1].min())
    return {"median_distance_m": float(np.median(np.abs(_sdf(body, p)))),
            "height_over_stature": float(np.ptp(p[:, 1]) / stature),
            "torso_cover_deg": float(torso_cover_deg(p, mesh.faces, body, lm))}


def verdict(name: str, row: dict) -> str:
    """right, refused (one line; `fix_works` says whether the fix it names passes the checks) or wrong."""
    stated = STATED.get(name, "binding")
    if not row["placed"]:
        return "refused" if row["inspect_error"] else "failed"
    if stated == "not on a body":
        return "wrong"
    if stated in (None, "binding"):
        return "right"
    return "right" if row["unit"] == stated else "wrong"


def run_case(name: str, path: Path, overrides: list[str], work: Path, body, fit: bool, samples: int,
             epochs: int) -> dict:
    folder = work / re.sub(r"[^\w.-]+", "_", name)
    row: dict = {"garment": name, "file": str(path.relative_to(CORPUS)), "overrides": overrides}
    rc, text, secs = pbc("garment", "inspect", str(path), *overrides, "--out", str(folder / "inspect"))
    (folder).mkdir(parents=True, exist_ok=True)
    (folder / "inspect.log").write_text(text)
    m = PLACED.search(text)
    row.update(placed=rc == 0, inspect_rc=rc, inspect_s=round(secs, 1), inspect_error=error_line(text),
               kind=m.group(1) if m else None,
               unit=("kept (m)" if m and m.group(2) is None else (m.group(2) if m else None)))
    if path.suffix == ".mhclo" and rc == 0:
        row.update(kind="mhclo", unit="binding")
    if rc == 0 and (folder / "inspect" / "fitted.obj").is_file():
        row.update(placement_figures(folder / "inspect" / "fitted.obj", body))
    row["verdict"] = verdict(name, row)
    fit_dir = folder / "fit"
    rc, text, secs = pbc("garment", "fit", str(path), *overrides, "--until", "checks", "--out", str(fit_dir))
    (folder / "checks.log").write_text(text)
    row.update(checks=rc == 0, checks_s=round(secs, 1), checks_error=error_line(text))
    refusal = row["inspect_error"] or row["checks_error"]
    fix = FIX.findall(refusal or "")
    if refusal and fix:  # the fix a refusal names, tried as the user would: does it work?
        overrides = [*overrides, fix[0]]
        row["fix"] = fix[0]
        rc, text, secs = pbc("garment", "fit", str(path), *overrides, "--until", "checks", "--out",
                             str(folder / "fixed"))
        (folder / "fixed.log").write_text(text)
        row.update(fix_works=rc == 0, fix_error=error_line(text), checks_s=round(row["checks_s"] + secs, 1))
        fit_dir = folder / "fixed"
        if rc == 0 and (fit_dir / "inspect" / "fitted.obj").is_file():
            row["fixed"] = placement_figures(fit_dir / "inspect" / "fitted.obj", body)
    if fit and rc == 0 and (row["checks"] or row.get("fix_works")):
        rc, text, secs = pbc("garment", "fit", str(path), *overrides, "--samples", str(samples), "--epochs",
                             str(epochs), "--out", str(fit_dir))
        (folder / "fit.log").write_text(text)
        row.update(fit_rc=rc, fit_min=round(secs / 60.0, 2), fit_error=error_line(text))
        manifest = fit_dir / "data" / "manifest.json"
        if manifest.is_file():
            counts = json.loads(manifest.read_text()).get("counts", {})
            row.update(kept=counts.get("kept"), asked=counts.get("requested"), discarded=counts.get("discarded"))
        elif "was discarded" in (row["fit_error"] or ""):  # generate refuses a dataset with no drape kept
            row.update(kept=0, asked=samples)
        score = re.search(r"([\d.]+) cm \(whole model\), ([\d.]+) cm \(the training mean shape\)", text)
        if score:
            row.update(model_cm=float(score.group(1)), mean_cm=float(score.group(2)))
    return row


def table(rows: list[dict]) -> str:
    head = (f"{'garment':<44} {'verdict':<8} {'kind':<7} {'unit':<10} {'dist cm':>7} {'h/stat':>6} {'cover':>5} "
            f"{'checks':<7} {'fix':<5} {'kept':>7} {'min':>5} {'model/mean cm':>14}")
    lines = [head, "-" * len(head)]
    for r in rows:
        kept = f"{r['kept']}/{r['asked']}" if r.get("asked") else "-"
        score = f"{r['model_cm']:.2f}/{r['mean_cm']:.2f}" if "model_cm" in r else "-"
        dist = f"{100 * r['median_distance_m']:.1f}" if "median_distance_m" in r else "-"
        hs = f"{r['height_over_stature']:.2f}" if "height_over_stature" in r else "-"
        cover = f"{r['torso_cover_deg']:.0f}" if r.get("torso_cover_deg") == r.get("torso_cover_deg") and \
            "torso_cover_deg" in r else "-"
        lines.append(f"{r['garment']:<44} {r['verdict']:<8} {str(r.get('kind')):<7} {str(r.get('unit')):<10} "
                     f"{dist:>7} {hs:>6} {cover:>5} {'pass' if r['checks'] else 'refused':<7} "
                     f"{'-' if 'fix' not in r else ('works' if r['fix_works'] else 'no'):<5} {kept:>7} "
                     f"{r.get('fit_min', '-')!s:>5} {score:>14}")
    for r in rows:
        for key in ("inspect_error", "checks_error", "fix_error", "fit_error"):
            if r.get(key):
                lines.append(f"  {r['garment']}: {key.split('_')[0]}: {r[key][:400]}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fit", action="store_true", help="a small fit of each garment that passes the checks")
    ap.add_argument("--samples", type=int, default=12, help="drapes of the small fit (default 12)")
    ap.add_argument("--epochs", type=int, default=5, help="epochs of the small fit (default 5)")
    ap.add_argument("--only", default="*", help="a glob on the garments' names (default: every garment)")
    ap.add_argument("--work", type=Path, default=Path.home() / ".cache" / "pbc" / "corpus_garments")
    ap.add_argument("--out", type=Path, help="write results.json here")
    args = ap.parse_args(argv)
    if not (CORPUS / "README.md").is_file():
        raise SystemExit(f"the corpus is missing at {CORPUS}: put ../shared/corpus beside the repository")
    from bench.drape import device_name  # noqa: PLC0415 - the sibling benchmark's device line, after sys.path
    from pbc.core.config import load_config
    from pbc.geometry.body import body_from_config

    body = body_from_config(load_config(["body=anny"]).body)
    args.work.mkdir(parents=True, exist_ok=True)
    todo = []
    for name, path, over in cases(CORPUS):
        if path.suffix == ".mhclo":
            places = outfit_places(path, args.work)
            todo += [(f"{name}:{p}", path, [f"garment.piece={p}"]) for p in places] or [(name, path, [])]
        else:
            todo.append((name, path, over))
    rows = []
    for name, path, over in todo:
        cached = args.work / (re.sub(r"[^\w.-]+", "_", name) + ".json")
        if cached.is_file():  # a row of an earlier run whose fit kept no drape: counted as 0 of the samples asked
            row = json.loads(cached.read_text())
            if "was discarded" in (row.get("fit_error") or "") and "asked" not in row:
                row.update(kept=0, asked=args.samples)
                cached.write_text(json.dumps(row, indent=1))
        if not fnmatch.fnmatch(name, args.only):
            continue
        done = args.work / (re.sub(r"[^\w.-]+", "_", name) + ".json")
        if done.is_file() and (not args.fit or "fit_rc" in json.loads(done.read_text())
                               or not json.loads(done.read_text())["checks"]):
            rows.append(json.loads(done.read_text()))
            continue
        print(f"[{len(rows) + 1}/{len(todo)}] {name} ...", flush=True)
        row = run_case(name, path, over, args.work, body, args.fit, args.samples, args.epochs)
        done.write_text(json.dumps(row, indent=1))
        rows.append(row)
    print(table(rows))
    fitted = [r for r in rows if r.get("asked")]
    worst_kept = min((r["kept"] / r["asked"] for r in fitted), default=float("nan"))
    figures = {
        "device": device_name(None),
        "garments": len(rows),
        "right": sum(r["verdict"] == "right" for r in rows),
        "refused": sum(r["verdict"] == "refused" for r in rows),
        "wrong": sum(r["verdict"] == "wrong" for r in rows),
        "failed": sum(r["verdict"] == "failed" for r in rows),
        "pass_checks": sum(bool(r["checks"]) for r in rows),
        "refused_with_a_fix_that_works": sum(bool(r.get("fix_works")) for r in rows),
        "refused_without_a_working_fix": sum(not r["checks"] and not r.get("fix_works") for r in rows),
        "fitted": len(fitted),
        "worst_kept_fraction": worst_kept,
        "kept_target_met": all(r["kept"] / r["asked"] >= TARGETS["kept"] for r in fitted),
        "targets": TARGETS,
    }
    for key in ("wrong", "kept"):
        met = figures["wrong"] == 0 if key == "wrong" else figures["kept_target_met"]
        print(f"target {key}: {'met' if met else 'NOT met'}")
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "garments.json").write_text(json.dumps({"figures": figures, "rows": rows}, indent=1))
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
