"""The documentation site (mkdocs.yml, `make docs`) builds with `mkdocs build --strict`: every link and anchor
between the pages resolves, every snippet (CHANGELOG.md, sweeps/README.md, patches/README.md) is found, and every
API page renders from pbc's docstrings. A warning fails the build, and so this test."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# a page of each kind: the home page, a guide, the results index and a results page, an API page, the snippets
PAGES = ("index.html", "getting-started/index.html", "motion/index.html", "results/index.html",
         "results/starter/index.html", "architecture/index.html", "api/motion/index.html",
         "api/inference/index.html", "changelog/index.html", "sweeps/index.html")


def build_site(out: Path) -> subprocess.CompletedProcess:
    """`mkdocs build --strict -d out` from the repository root (the snippets' base path), with this interpreter's
    mkdocs; the notice Material prints about its successor is silenced."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(out)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def test_the_site_builds_strictly_with_its_guides_results_api_and_changelog(tmp_path):
    site = tmp_path / "site"
    res = build_site(site)
    warnings = [line for line in (res.stdout + res.stderr).splitlines() if "WARNING" in line or "ERROR" in line]
    assert res.returncode == 0, "mkdocs build --strict failed:\n" + "\n".join(warnings or [res.stderr[-3000:]])
    missing = [page for page in PAGES if not (site / page).is_file()]
    assert not missing, f"pages not built: {missing}"
    # the API pages come from the docstrings: a function of pbc.motion.known and the predictor's class
    assert "nearest_known" in (site / "api/motion/index.html").read_text()
    assert "ClothPredictor" in (site / "api/inference/index.html").read_text()
    # the snippets were included, not left as their marker: the changelog's newest date heading is on its page
    newest = next(line[3:].strip() for line in (ROOT / "CHANGELOG.md").read_text().splitlines()
                  if line.startswith("## "))
    changelog = (site / "changelog/index.html").read_text()
    assert newest in changelog and "--8&lt;--" not in changelog and "--8<--" not in changelog
    # the figures the pages show are copied beside them
    assert (site / "figures/starter_walk.png").is_file()
