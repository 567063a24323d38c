"""`pbc garment fit`'s budget (pbc.jobs.fit_plan): the budget's text, the plan a budget and measured costs make,
and the refusal of a budget too small, naming one that plans."""

from __future__ import annotations

import dataclasses
import re

import pytest

from pbc.jobs.fit_plan import Costs, budget_text, fit_settings, parse_budget, plan_fit, smallest_budget
from pbc.jobs.garment_fit import Fit, last_epoch_seconds, max_time


def costs(**kw) -> Costs:
    """Costs like a MakeHuman top's on the 2-core CPU: a drape 1.5 s, the CNN 80 ms a row, the PCA net 2 ms."""
    base = dict(spent_s=120.0, start_s=25.0, drape_s=1.5, kept=0.9, epoch_row_s={"pca": 0.002, "whole": 0.08},
                epoch_fixed_s={"pca": 0.3, "whole": 1.0}, mirror=True, max_epochs={"pca": 400, "whole": 200})
    return Costs(**{**base, **kw})


@pytest.mark.parametrize("text, seconds", [("60m", 3600), ("1h30m", 5400), ("1.5h", 5400), ("90s", 90),
                                           ("1h", 3600), (" 15M ", 900)])
def test_a_budget_reads_hours_minutes_and_seconds(text, seconds):
    assert parse_budget(text) == seconds
    assert parse_budget(budget_text(seconds)) == seconds


@pytest.mark.parametrize("text, fix", [("60", "write 60m"), ("1h30", "write 1h30m"), ("1m30", "write 1m30s"),
                                       ("an hour", "e.g. 60m"), ("0m", "above zero")])
def test_a_budget_written_wrong_is_one_line_with_how_to_write_it(text, fix):
    with pytest.raises(ValueError) as err:
        parse_budget(text)
    assert fix in str(err.value) and "\n" not in str(err.value)


def test_the_plan_spends_the_budget_and_no_more():
    s = fit_settings()
    for budget in (900, 3600, 5400):
        plan = plan_fit(budget, costs(), s)
        total = costs().spent_s + sum(plan.step_s.values())
        # within the budget less its margin, and most of it used
        assert 0.8 * budget * (1 - s.margin) <= total <= budget * (1 - s.margin) + 1
        assert s.samples_min <= plan.samples <= s.samples_max
        assert all(m.epochs * costs().epoch_s(m.name, plan.samples) <= m.seconds + 1e-6 for m in plan.models)
    # a bigger budget buys more drapes
    assert plan_fit(900, costs(), s).samples < plan_fit(3600, costs(), s).samples < plan_fit(5400, costs(), s).samples


def test_a_model_its_share_cannot_train_is_left_out_saying_what_budget_trains_it():
    s = fit_settings()
    plan = plan_fit(900, costs(), s)  # the CNN at 80 ms a row: 10 epochs do not fit a quarter of an hour
    assert [m.name for m in plan.models] == ["pca"]
    why = plan.left_out["whole"]
    more = re.search(r"--budget (\S+) would train it", why).group(1)
    assert "10 epochs" in why and parse_budget(more) > 900
    # a cheap CNN is trained beside the PCA net, each within its share
    both = plan_fit(3600, costs(epoch_row_s={"pca": 0.002, "whole": 0.005}), s)
    assert sorted(m.name for m in both.models) == ["pca", "whole"]
    assert sum(m.seconds for m in both.models) <= 3600


def test_fixed_drapes_keep_their_count_and_the_text_names_each_step():
    plan = plan_fit(3600, costs(), fit_settings(), samples=200)
    assert plan.samples == 200
    text = "\n".join(plan.lines())
    for step in ("data: 200 drapes", "motion: ", "models: pca (fit_pca)", "preview: ", "done about"):
        assert step in text
    assert "motion" not in "\n".join(plan_fit(3600, costs(), fit_settings(), motion=False).lines())


def test_a_budget_too_small_names_the_smallest_that_plans():
    s = fit_settings()
    c = costs(drape_s=6.0)
    need = smallest_budget(c, s)
    with pytest.raises(ValueError) as err:
        plan_fit(need * 0.6, c, s)
    named = parse_budget(re.search(r"give --budget (\S+) or more", str(err.value)).group(1))
    assert abs(named - need) < 2 and "\n" not in str(err.value)
    plan = plan_fit(named, c, s)  # the budget it names plans
    assert plan.models and plan.samples >= s.samples_min


def test_a_fit_refuses_a_budget_below_the_floor_or_beside_both_counts_before_anything(tmp_path):
    garment = tmp_path / "g.obj"
    garment.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"--budget 1m: below 3m .* give --budget 15m"):
        Fit(garment, [], tmp_path / "fit", budget="1m")
    with pytest.raises(ValueError, match="nothing to plan"):
        Fit(garment, [], tmp_path / "fit", samples=10, epochs=5, budget="15m")
    with pytest.raises(ValueError, match="has no unit"):
        Fit(garment, [], tmp_path / "fit", budget="60")
    assert not (tmp_path / "fit").exists()
    assert Fit(garment, [], tmp_path / "fit", samples=10, epochs=5).asked["budget"] is None


def test_an_epoch_is_timed_between_its_log_lines():
    log = ("[2026-12-02 04:06:13,000][pbc.models.progress][INFO] - epoch 1/3  train loss 1  v 1  2.0 s/epoch  ETA 4s\n"
           "[2026-12-02 04:06:14,409][pbc.models.progress][INFO] - epoch 2/3  train loss 1  v 1  1.7 s/epoch  ETA 1s\n"
           "[2026-12-02 04:06:14,820][pbc.models.progress][INFO] - epoch 3/3  train loss 1  v 1  1.3 s/epoch  ETA 0s\n")
    assert last_epoch_seconds(log) == pytest.approx(0.411, abs=1e-3)
    # without the log's stamps: from the means (3 x 1.3 - 2 x 1.7)
    bare = "\n".join(line.split(" - ", 1)[1] for line in log.splitlines())
    assert last_epoch_seconds(bare) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="no epoch line"):
        last_epoch_seconds("nothing here")
    assert max_time(3725) == "'00:01:02:05'"


def test_the_settings_are_held_to_their_bounds(tmp_path):
    bad = tmp_path / "fit.yaml"
    text = (fit_settings.__wrapped__.__defaults__[0]).read_text().replace("drapes: 12", "drapes: 1")
    bad.write_text(text)
    with pytest.raises(ValueError, match="probe.drapes"):
        fit_settings.__wrapped__(bad)
    assert dataclasses.is_dataclass(fit_settings())


def test_a_refused_plan_removes_what_the_fit_wrote_before_its_drapes_and_never_a_drape(tmp_path):
    garment = tmp_path / "g.obj"
    garment.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    out = tmp_path / "fit"
    for d in ("inspect", "plan/probe", "logs"):
        (out / d).mkdir(parents=True)
        (out / d / "x.txt").write_text("x")
    (out / "cage.json").write_text("{}")
    (out / "fit.json").write_text("{}")
    fit = Fit(garment, [], out)
    fit.discard_before_drapes()
    assert not out.exists()
    # a fit holding drapes keeps everything
    (out / "data" / "work" / "samples").mkdir(parents=True)
    (out / "data" / "work" / "samples" / "000000.npz").write_bytes(b"a drape")
    (out / "fit.json").write_text("{}")
    fit.discard_before_drapes()
    assert (out / "fit.json").is_file() and (out / "data" / "work" / "samples" / "000000.npz").is_file()


def test_time_the_drapes_did_not_take_goes_to_the_training():
    from pbc.jobs.fit_plan import replan_training

    s = fit_settings()
    plan = plan_fit(900, costs(), s)
    assert [m.name for m in plan.models] == ["pca"] and "whole" in plan.left_out
    before = [(m.name, m.seconds) for m in plan.models]
    # as planned: nothing changes
    planned_left = 900 * (1 - s.margin) - costs().spent_s - plan.step_s["data"] - plan.step_s["motion"]
    assert not replan_training(plan, s, int(plan.samples * costs().kept), planned_left)
    assert [(m.name, m.seconds) for m in plan.models] == before
    # the drapes took a minute: the CNN's 10 epochs fit now, beside the PCA net, within what is left
    left = 900 * (1 - s.margin) - costs().spent_s - 60
    assert replan_training(plan, s, int(plan.samples * costs().kept), left)
    assert sorted(m.name for m in plan.models) == ["pca", "whole"] and not plan.left_out
    assert sum(m.seconds for m in plan.models) <= left
