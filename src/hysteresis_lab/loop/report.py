"""The loop's report as a notebook page (``loop_report.md``) and the figures it links.

One section per round: the fit, the before/after on the test recordings and the validation
decision (a refit), the residual evidence (figures beside the report, the ranked
diagnosis), the effects the data could not judge for lack of excitation with the recordings
to add for them, the effect added and why, and its operators' excitation; then the result
and the data roles. Everything is read from ``loop_report.json``'s document, so the page and the
JSON cannot disagree; the figures are drawn from what a round already computed (no model
runs).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from typing import Any

from hysteresis_lab.effects.base import FeatureContext
from hysteresis_lab.loop.diagnosis.ranking import BlockCounts
from hysteresis_lab.loop.figures import (
    DPI,
    ResidualEvidence,
    effect_figure,
    residual_figure,
    scores_figure,
)
from hysteresis_lab.run_folder import LoopFolder

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------- figures
def write_round_figures(
    folder: LoopFolder,
    number: int,
    entry: dict[str, Any],
    evidence: ResidualEvidence | None,
    context: FeatureContext,
    min_score: float,
) -> None:
    """Round ``number``'s report figures, their paths (relative to the loop folder) added to
    ``entry["figures"]``: the residual and the effect scores when the round diagnosed its
    model (``evidence`` is that model's free run), and the added effect's signals against
    the standing model's residual when the round adds one."""
    started = time.perf_counter()
    figures = entry.setdefault("figures", {})
    if entry.get("diagnosis") and evidence is not None:
        title = f"round {number}: free run of the model with effects {entry['effects'] or '[]'}"
        figures["residual"] = _save(folder, folder.figure(number, "residual"),
                                    residual_figure(evidence, title))
        figures["scores"] = _save(folder, folder.figure(number, "scores"),
                                  scores_figure(entry["diagnosis"], min_score, entry["added"]))
    if entry.get("added") and evidence is not None:
        name = f"added_{entry['added']}"
        figures["added"] = _save(folder, folder.figure(number, name),
                                 effect_figure(evidence, entry["added"], context))
    log.debug("round %d report figures in %.2f s", number, time.perf_counter() - started)


def _save(folder: LoopFolder, path: Any, figure: Any) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=DPI)
    return folder.relative(path)


# ---------------------------------------------------------------------------- terminal
def round_line(report: Mapping[str, Any], number: int) -> str:
    """Round ``number`` in one terminal line: the effect it tried, the evidence that named
    it, kept or dropped, and the held-out loss and the tests' mean free-run RMSE before ->
    after (the start: its scores)."""
    r, unit = report["rounds"][number], report["units"]["y"]
    decision = r.get("decision")
    if decision is None:
        what = "the start, " if number == 0 else ""
        loss = (r.get("held_out") or {}).get("loss")
        held = "" if loss is None else f", held-out loss {loss:.4g}"
        line = (f"round {number} ({what}effects {r['effects'] or '[]'}): test free-run RMSE "
                f"{r['mean_rmse_free_run']:.4g} {unit}{held}")
        return line + (f"; {r['note']}" if r.get("note") and not r.get("diagnosis") else "")
    effect, held = decision["effect"], decision["held_out_loss"]
    named = [d for d in report["rounds"][decision["against_round"]].get("diagnosis", [])
             if d["effect"] == effect]
    evidence = (f" (explained {named[0]['score']:.1%} of round {decision['against_round']}'s "
                f"held-out residual, p {named[0]['p_value']:.2g})" if named else "")
    after_loss = "not judged" if held["after"] is None else f"{held['after']:.4g}"
    line = (f"round {number}: + {effect}{evidence}, "
            f"{'kept' if decision['kept'] else 'dropped'}: held-out loss "
            f"{held['before']:.4g} -> {after_loss}")
    if decision["kept"] or "rejected_refit" in r:
        before, after = before_after(report, number)
        b, a = before["mean_rmse_free_run"], after["mean_rmse_free_run"]
        line += f", test free-run RMSE {b:.4g} -> {a:.4g} {unit} ({_change(b, a)})"
    return line


def result_line(report: Mapping[str, Any]) -> str:
    """The loop's result in one terminal line: the standing model, the tests' mean free-run
    RMSE from the start to it, and why the loop ended."""
    rounds, unit = report["rounds"], report["units"]["y"]
    end = rounds[-1].get("note") if rounds else None
    why = f"; {end}" if end else ""
    if report.get("stopped"):
        why = f"; stopped: {report['stopped']}"
    if report.get("result") is None:
        return f"no result: the start model's free run diverges{why}"
    result = rounds[report["result"]]
    first, last = rounds[0]["mean_rmse_free_run"], result["mean_rmse_free_run"]
    return (f"result: round {report['result']}, effects {result['effects'] or '[]'}: test "
            f"free-run RMSE {first:.4g} -> {last:.4g} {unit} ({_change(first, last)}){why}")


# ---------------------------------------------------------------------------- markdown
def loop_markdown(report: Mapping[str, Any]) -> str:
    """The notebook page: a section per round, then the result and the data roles."""
    lines = [
        f"# Residual loop: {report['model']} on {report['data']}",
        "",
        f"Start: `{start_label(report['start'])}`.",
        "",
        *_rules_lines(report.get("settings")),
    ]
    if report.get("stopped"):
        lines += ["", f"**The loop stopped before its end**: {report['stopped']}"]
    unit = report["units"]["y"]
    rounds = report["rounds"]
    for number in range(len(rounds)):
        lines += ["", *_round_section(report, number, unit)]
    lines += ["", *_result_section(report, unit), "", *_roles_lines(report["roles"])]
    return "\n".join(lines) + "\n"


def start_label(start: Mapping[str, Any]) -> str:
    """The loop's start as the overrides that give it, e.g. ``model=linear effects=[]``."""
    return f"model={start['model']} effects=[{','.join(start['effects'])}]"


def _rules_lines(settings: Mapping[str, Any] | None) -> list[str]:
    """The significance and keep rules the decisions below follow (older reports: none)."""
    if not settings:
        return []
    return [
        f"An effect is significant when its held-out score reaches loop.min_score="
        f"{settings['min_score']:g} at p <= loop.alpha={settings['alpha']:g} "
        f"(loop.significance={settings['significance']}), every fold's held-out blocks voting; "
        f"a refit is kept when its free run is stable on every one of loop.folds="
        f"{settings.get('folds', '?')} folds, and its held-out loss beats the standing "
        "model's pooled over the folds (by more than the share "
        f"loop.min_refit_gain={settings['min_refit_gain']:g}) and on a majority of them. "
        "The folds choose; what they chose is then refitted on the whole identification "
        "record, and that model is the round's result (its test numbers below).",
    ]


def _round_section(report: Mapping[str, Any], number: int, unit: str) -> list[str]:
    """One round: fit, before/after and decision (a refit), evidence, the effect added."""
    r = report["rounds"][number]
    decision = r.get("decision")
    lines = [f"## {_round_title(r, number)}", "", "### Fit", "", *_fit_lines(r, unit)]
    if decision is not None:
        lines += ["", "### Before / after on the tests", "",
                  *before_after_table(report, number, unit)]
        lines += ["", "### Validation decision", "", *_decision_lines(r, unit)]
    if r.get("diagnosis"):
        lines += ["", "### Residual evidence", "", *_evidence_lines(r, report["roles"])]
    if r.get("under_excited"):
        lines += ["", "### Not judged: recordings to add", "", *_advice_lines(r)]
    undecided = _undecided_lines(report, r)
    if undecided:
        lines += ["", "### Undecided: more held-out data would decide", "", *undecided]
    if decision is None and not r.get("diagnosis"):
        return lines  # a start that diverges: nothing was diagnosed
    lines += ["", "### Effect added" if decision is None or decision["kept"]
              else "### Next effect", "", *_added_lines(report, number)]
    return lines


def _round_title(r: Mapping[str, Any], number: int) -> str:
    decision = r.get("decision")
    if decision is None:  # the start (or a round of a report older than decisions)
        what = "the start, " if number == 0 else ""
        return f"Round {number}: {what}effects {r['effects'] or '[]'}"
    verdict = "kept" if decision["kept"] else "dropped"
    return f"Round {number}: + {decision['effect']}, {verdict}"


def _fit_lines(r: Mapping[str, Any], unit: str) -> list[str]:
    """The model fitted: its effects, the refit rate, and (a standing model) held-out."""
    decision = r.get("decision")
    if decision is None:
        lines = [f"- effects declared: {r['effects'] or '[]'}"]
    else:
        lines = [f"- refit of round {decision['against_round']}'s model with "
                 f"'{decision['effect']}': effects {r['effects']}"]
    lines += _refit_rate_lines(r)
    chosen, fitted = r.get("chosen_on"), r.get("fitted_on")
    if chosen:
        where = (f"the result refitted on the whole identification record "
                 f"({', '.join(fitted['recordings'])}: {fitted['samples']} samples)"
                 if fitted else "not refitted on the whole record (the folds dropped it)")
        held = (f", holding out {'; '.join(chosen['held_out'])} in turn"
                if chosen.get("held_out") else "")
        lines.append(f"- chosen on {chosen['folds']} folds (each trained on "
                     f"{', '.join(map(str, chosen['samples']))} samples{held}); {where}")
        if fitted and fitted.get("length"):
            lines.append(f"- the whole-record refit trained {fitted['length']}")
    if r.get("final_refit"):
        lines.append(f"- {r['final_refit']}")
    if decision is None or decision["kept"]:
        lines += _held_out_lines("held out on the folds (each fold's model)", r.get("held_out"),
                                 unit)
    if decision is None and r.get("note") and not r.get("diagnosis"):
        lines.append(f"- {r['note']}")  # a start that diverges
    return lines


def before_after_table(report: Mapping[str, Any], number: int, unit: str) -> list[str]:
    """Free-run RMSE per test recording of the model the refit started from (before) and of
    the refit (after, kept or not), and the change."""
    r = report["rounds"][number]
    if not r["decision"]["kept"] and "rejected_refit" not in r:
        return ["The folds dropped this refit before it was fitted on the whole identification "
                "record: it has no test scores."]
    before, after = before_after(report, number)
    against = r["decision"]["against_round"]
    kept = "" if r["decision"]["kept"] else ", not kept"
    lines = [
        f"| test | before: round {against} [{unit}] | after: the refit{kept} [{unit}] | change |",
        "|---|---|---|---|",
    ]
    for name, b in before["tests"].items():
        a = after["tests"][name]["rmse_free_run"]
        b = b["rmse_free_run"]
        lines.append(f"| {name} | {b:.4g} | {a:.4g} | {_change(b, a)} |")
    b, a = before["mean_rmse_free_run"], after["mean_rmse_free_run"]
    lines.append(f"| **mean** | {b:.4g} | {a:.4g} | {_change(b, a)} |")
    return lines


def before_after(
    report: Mapping[str, Any], number: int
) -> tuple[Mapping[str, Any], Mapping[str, Any]]:
    """The scores (``tests``, ``mean_rmse_free_run``) before and after round ``number``'s
    refit: the model it started from, and the refit (a dropped refit's are
    ``rejected_refit``; the round's own are the model that stands)."""
    r = report["rounds"][number]
    if r["decision"]["kept"]:
        return report["rounds"][r["decision"]["against_round"]], r
    return r, r["rejected_refit"]


def _decision_lines(r: Mapping[str, Any], unit: str) -> list[str]:
    """Kept or dropped, and why: held-out loss before/after, the training validation loss."""
    decision = r["decision"]
    held = decision["held_out_loss"]
    lines = [f"**{'Kept' if decision['kept'] else 'Dropped'}**: {decision['reason']}.", ""]
    after = "not judged" if held["after"] is None else f"{held['after']:.4g}"
    change = "" if held["after"] is None else f" ({_change(held['before'], held['after'])})"
    lines.append(f"- held-out loss pooled over the folds (MSE / variance): round "
                 f"{decision['against_round']} {held['before']:.4g}, refit {after}{change}")
    loss = r.get("refit_validation_loss")
    if loss:
        lines.append(f"- training validation loss (scaled): start {loss['start']:.4g}, "
                     f"refit {loss['refit']:.4g} ({_change(loss['start'], loss['refit'])})")
    lines += _compared_lines(r.get("compared"))
    folds = decision.get("fold_losses")
    if folds:
        pairs = ", ".join(f"{b:.4g} -> {a:.4g}" for b, a in
                          zip(folds["before"], folds["after"], strict=True))
        lines.append(f"- per fold (before -> after): {pairs}")
    if not decision["kept"]:
        lines += _held_out_lines("the dropped refit's held-out folds",
                                 r.get("rejected_held_out"), unit)
    return lines


def _compared_lines(compared: Sequence[Mapping[str, Any]] | None) -> list[str]:
    """The confounded effects refitted in a round, each with its cross-validated numbers,
    and those the folds cannot tell from the best."""
    if not compared:
        return []
    lines = ["- effects the diagnosis could not tell apart, each refitted on the folds "
             "(pooled held-out loss; per fold):"]
    for row in compared:
        folds = ", ".join(f"{x:.4g}" for x in row["fold_losses"])
        lines.append(f"  - {row['effect']}: {row['held_out_loss']:.4g} ({folds})")
    tied = [row["effect"] for row in compared[1:] if not row["told_apart"]]
    if tied:
        lines.append(f"  - the folds cannot tell {compared[0]['effect']} from "
                     f"{', '.join(tied)}: it is not lower on a majority of them")
    return lines


def _evidence_lines(r: Mapping[str, Any], roles: Mapping[str, Sequence[str]]) -> list[str]:
    """The figures of the round's residual and the ranked diagnosis."""
    figures = r.get("figures", {})
    lines = [f"The free run of this round's model on the diagnosis recordings "
             f"({', '.join(roles.get('diagnosis', [])) or 'none'}):", ""]
    if "residual" in figures:
        lines += [f"![free-run residual over time and its spectrum]({figures['residual']})", ""]
    if "scores" in figures:
        lines += [f"![missing effects: held-out scores]({figures['scores']})", ""]
    if "diagnostics" in figures:
        lines += [f"Correlation tests and residual against the input: "
                  f"[{figures['diagnostics']}]({figures['diagnostics']}).", ""]
    lines += [_diagnosis_line(d) for d in r["diagnosis"]]
    if r.get("reported"):
        lines.append(
            f"- reported, not added: {', '.join(r['reported'])} (does not depend on the "
            "input: free run cannot predict it; no gain is claimed)"
        )
    if r.get("not_carried"):
        lines.append(f"- significant, but model '{r['effects']}' has no block for: "
                     f"{', '.join(r['not_carried'])}")
    for held in r.get("not_added_under_excited", []):
        lines.append(f"- significant, not added (foreign to data.plant={held.get('plant')}, "
                     f"loop.add_under_excited=false): {held['reading']}")
    return lines


def _added_lines(report: Mapping[str, Any], number: int) -> list[str]:
    """The effect added (or tried next) and why, its figure and its operators' excitation."""
    r = report["rounds"][number]
    dropped = bool(r.get("rejected"))
    if not r["added"]:
        note = r.get("note") if not dropped else "nothing else significant to try"
        return [f"- added: None ({note})" if note else "- added: None"]
    lines = [f"- added: {r['added']}" + (f" ({r['note']})" if r.get("note") and not dropped
                                         else "")]
    chosen_by = _diagnosed_round(report["rounds"], number)
    score = next((d for d in report["rounds"][chosen_by]["diagnosis"]
                  if d["effect"] == r["added"]), None)
    if score is not None:
        tried = f"next on round {chosen_by}'s diagnosis, " if dropped else ""
        lines.append(f"- why: {tried}the most significant effect not yet tried that free run "
                     f"can predict: score {score['score']:.3f}, p {score['p_value']:.3g}"
                     f"{' (significant)' if score['significant'] else ''}")
        lines.append(f"  - {score['evidence']}")
    if r.get("alternatives"):
        lines.append(f"- refitted beside it, its scores too close to tell apart "
                     f"(loop.confounded_margin): {', '.join(r['alternatives'])}; the folds "
                     "keep the best")
    figure = r.get("figures", {}).get("added")
    if figure:
        lines += ["", f"![the residual and what '{r['added']}' reproduces of it]({figure})", ""]
    lines += _excitation_lines(r)
    return lines


def _advice_lines(r: Mapping[str, Any]) -> list[str]:
    """Effects the round's data could not judge for lack of excitation, and the recordings
    that would show them (`hysteresis_lab.loop.advice`)."""
    lines = []
    for entry in r["under_excited"]:
        lines.append(f"- {entry['advice']}")
        if entry.get("override"):
            lines.append(f"  - rerun with: `{' '.join(entry['override'])}`")
    return lines


def _undecided_lines(report: Mapping[str, Any], r: Mapping[str, Any]) -> list[str]:
    """Where the loop stops with nothing added: the effects whose score reaches
    loop.min_score at a p above loop.alpha (and not judged for lack of excitation), with how
    their held-out blocks voted (`hysteresis_lab.loop.diagnosis.ranking.BlockCounts`)."""
    settings = report.get("settings") or {}
    if r.get("added") or r.get("rejected") or not settings:
        return []
    unjudged = {entry["effect"] for entry in r.get("under_excited", [])}
    lines = []
    for d in r.get("diagnosis", []):
        blocks = d.get("blocks")
        if (d["significant"] or not d["tested"] or not d["predictable"] or blocks is None
                or d["effect"] in unjudged or d["score"] < settings["min_score"]):
            continue
        votes = BlockCounts(**blocks)
        # the pooled test's floor; a per-recording test is one recording's blocks, Holm-adjusted
        floor = (f"; {votes.informative} blocks give at best p = {votes.smallest_p:.2g}"
                 if settings.get("significance", "pooled") == "pooled" else "")
        lines.append(
            f"- {d['effect']}: score {d['score']:.3f} at p {d['p_value']:.3g} (loop.alpha="
            f"{settings['alpha']:g}): of {votes.held_out} held-out blocks {votes.gaining} "
            f"gain, {votes.losing} lose and {votes.silent} carry no evidence{floor}"
        )
    if lines:
        lines.append(
            "- each held-out block (of every fold) is one vote of the significance test: more "
            "identification data (recordings in data.train=[...]) give more votes"
        )
    return lines


def _diagnosed_round(rounds: Sequence[Mapping[str, Any]], number: int) -> int:
    """The round whose diagnosis chose round ``number``'s next effect: the last one up to
    it that diagnosed its model."""
    return max(i for i in range(number + 1) if rounds[i].get("diagnosis"))


def _excitation_lines(entry: Mapping[str, Any]) -> list[str]:
    """How hard the tests drive the added effect's operators beyond the identification data:
    per operator, and the reading."""
    excitation = entry.get("added_excitation")
    if not excitation:
        return []
    ratios = ", ".join(f"{name} {'never moved' if ratio is None else f'{ratio:.3g}x'}"
                       for name, ratio in excitation["ratios"].items())
    return [
        "- operator excitation, RMS on the tests over RMS on the identification data "
        f"(training and validation): {ratios}",
        f"  - {excitation['reading']}",
    ]


def _result_section(report: Mapping[str, Any], unit: str) -> list[str]:
    """The result: the standing model, and the tests' free-run RMSE over the kept rounds."""
    rounds = report["rounds"]
    lines = ["## Result", ""]
    if report.get("result") is None:
        return lines + ["**No result**: the start model's free run diverges (see round 0)."]
    result = rounds[report["result"]]
    lines += [f"The model of round {report['result']} stands: effects "
              f"{result['effects'] or '[]'}.", ""]
    kept = [i for i, r in enumerate(rounds) if not r.get("rejected")]
    lines.append(f"Free-run RMSE [{unit}] per test recording over the rounds whose model "
                 "stood (effects declared):")
    header = ["test"] + [f"round {i}: {rounds[i]['effects'] or '[]'}" for i in kept]
    lines += ["", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name in rounds[0]["tests"]:
        cells = [name] + [f"{rounds[i]['tests'][name]['rmse_free_run']:.4g}" for i in kept]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("| **mean** | " + " | ".join(
        f"{rounds[i]['mean_rmse_free_run']:.4g}" for i in kept) + " |")
    first, last = rounds[0]["mean_rmse_free_run"], result["mean_rmse_free_run"]
    lines += ["", f"Mean free-run RMSE {first:.4g} -> {last:.4g} {unit} "
              f"({_change(first, last)}).", ""]
    if report.get("plots", True):  # plots=false: no figures drawn
        lines.append(f"![test recordings: free run before and after]({LoopFolder.BEFORE_AFTER})")
    return lines


def _roles_lines(roles: Mapping[str, list[str]]) -> list[str]:
    """Which recordings (``name[a:b]``: samples a to b) played which role: which data chose
    and which fitted."""
    what = {
        "train": "fitted the result (the whole identification record)",
        "folds": "chose (cross-validation folds: each held out in turn, its models trained "
                 "on the rest)",
        "validation": "validation (judges every refit)",
        "diagnosis": "diagnosis (its residual chooses the effect)",
        "test": "test (the before/after numbers)",
    }
    return ["## Data roles", ""] + [
        f"- {what[role]}: {', '.join(names) or 'none'}" for role, names in roles.items()
    ]


def _held_out_lines(label: str, check: Mapping[str, Any] | None, unit: str) -> list[str]:
    """A model's free run on the held-out validation data: loss, RMSE, divergence."""
    if not check:
        return []
    rmse = ", ".join(f"{name} {value:.4g}" for name, value in check["rmse"].items())
    lines = [f"- {label}: loss {check['loss']:.4g} (MSE / variance), free-run RMSE "
             f"[{unit}] {rmse}"]
    if check["diverging"]:
        lines.append(f"  - free run diverges on {', '.join(check['diverging'])}")
    return lines


def _diagnosis_line(d: Mapping[str, Any]) -> str:
    """One effect of a round's diagnosis: its score and p-value, or why it was not tested."""
    if not d["tested"]:
        return f"- {d['effect']} (not tested): {d['evidence']}"
    bold = "**" if d["significant"] else ""
    blocks = d.get("blocks")
    votes = (f" ({blocks['gaining']} of {blocks['held_out']} blocks gain, "
             f"{blocks['losing']} lose)" if blocks else "")
    return f"- {bold}{d['effect']}{bold}: score {d['score']:.3f}, p {d['p_value']:.3g}{votes}"


def _refit_rate_lines(entry: Mapping[str, Any]) -> list[str]:
    """The learning rate a refit was chosen at and every tried rate's validation loss."""
    if entry.get("refit_lr") is None:
        return []
    settings = entry.get("refit_settings") or {}

    added = (entry.get("decision") or {}).get("effect")

    def label(c: Mapping[str, Any]) -> str:
        """Rate and place; the effect too where a compared alternative's (`compared`)."""
        where = " ".join(f"{key}={c[key]}" for key in settings if key in c)
        if c.get("effect") not in (None, added):
            where = f"{c['effect']} {where}".strip()
        return f"{where} {c['refit_lr']:.0e}" if where else f"{c['refit_lr']:.0e}"

    tried = ", ".join(
        f"{label(c)}: " + ("diverged" if c.get("diverged") else
                           f"{c['validation_loss']:.4g} (held out "
                           f"{c.get('held_out_loss', float('nan')):.4g})")
        for c in entry["refit_candidates"]
    )
    chosen = "".join(f", {key}={value}" for key, value in settings.items())
    return [f"- refit learning rate {entry['refit_lr']:.0e}{chosen} (validation loss per "
            f"candidate: {tried})"]


def _change(before: float, after: float) -> str:
    """Relative change as a signed percentage."""
    return f"{100 * (after - before) / before:+.1f} %" if before else "n/a"
