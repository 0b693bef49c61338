"""Which user model predicts a held-out participant's next turn best: per level, clusters, or pooled.

For each real session i (leave its PERSON out), three models are fitted on the other people's sessions
and predict session i's turns one at a time, each from the session's earlier turns only:

``per-level``     a Beta prior per level (mean and strength by the method of moments over the
                  other sessions, ``learn.users.beta_concentration``), its posterior mean;
``clusters``      the other sessions clustered as for the personalised policy (``learn.users.
                  hold_out``), each cluster's success per level, the posterior mixture over them
                  (prior = cluster sizes): what the live posterior does with ``kappa = inf``;
``psychometric``  ``core.psychometric``'s pooled model (hierarchical prior fitted on the others).

Predictions are clipped to [0.001, 0.999] for every model. Reported: the mean log-likelihood per
turn (95 % t-interval over people), the paired difference of each model to ``per-level``, and
calibration (10 bins of the predicted probability: expected calibration error and the bins), and
each session's span estimate (length at success rate R, 90 % interval) after all its turns.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from nao_trainer.core import evaluation, psychometric
from nao_trainer.core.people import people, per_person
from nao_trainer.learn.fitting import Turns
from nao_trainer.learn.users import beta_concentration, hold_out, leave_one_person_out, read_turns

MODELS: tuple[str, ...] = ("per-level", "clusters", "psychometric")
CLIP = 1e-3


def _counts(levels: np.ndarray, success: np.ndarray) -> np.ndarray:
    c = np.zeros(8)
    for lv, ok in zip(levels, success):
        c[2 * (lv - 1) + (0 if ok else 1)] += 1
    return c


def _session_counts(turns: Any) -> tuple[list[str], np.ndarray]:
    names = sorted(np.unique(turns.session).tolist())
    return names, np.array([_counts(turns.level[turns.session == s], turns.success[turns.session == s])
                            for s in names])


def _one(turns: Any, session: str, k: int, n_init: int, seed: int, rate: float) -> dict[str, Any]:
    split = hold_out(turns, session, k, n_init, seed)
    rest, own = split.rest, split.own
    names, counts = _session_counts(rest)
    # per level: Beta(m kappa, (1 - m) kappa) from the other sessions
    wins, n = counts[:, 0::2], counts[:, 0::2] + counts[:, 1::2]
    m = wins.sum(axis=0) / np.maximum(n.sum(axis=0), 1)
    kappa = np.array([beta_concentration(np.where(n[:, lv] > 0, wins[:, lv] / np.maximum(n[:, lv], 1), 0), n[:, lv])
                      for lv in range(4)])
    # clusters: success per level of each cluster's turns
    p_k, size = [], []
    for c in range(1, k + 1):
        mine = split.labels == c
        lv = rest.level[mine]
        rates = [float(rest.success[mine][lv == x].mean()) if np.any(lv == x) else float(m[x - 1]) for x in (1, 2, 3, 4)]
        p_k.append(rates)
        size.append(len(np.unique(rest.session[mine])))
    p_k = np.clip(np.array(p_k), CLIP, 1 - CLIP)
    log_prior = np.log(np.array(size, dtype=float) / sum(size))
    pooled = psychometric.fit(counts)
    ll = {name: [] for name in MODELS}
    preds: dict[str, list[tuple[float, int]]] = {name: [] for name in MODELS}
    c = np.zeros(8)
    for lv, ok in zip(own.level, own.success):
        i = lv - 1
        post = log_prior + c[0::2] @ np.log(p_k).T + c[1::2] @ np.log1p(-p_k).T
        w = np.exp(post - post.max())
        guess = {"per-level": (c[2 * i] + kappa[i] * m[i]) / (c[2 * i] + c[2 * i + 1] + kappa[i]),
                 "clusters": float(w @ p_k[:, i] / w.sum()),
                 "psychometric": float(pooled.predictive(c)[i])}
        for name, p in guess.items():
            p = min(max(p, CLIP), 1 - CLIP)
            ll[name].append(np.log(p if ok else 1 - p))
            preds[name].append((p, int(ok)))
        c[2 * i + (0 if ok else 1)] += 1
    span = pooled.span(c, rate)
    return {"session": session, "turns": int(len(own.level)), "ll": {k_: float(np.mean(v)) for k_, v in ll.items()},
            "preds": preds, "span": span, "model": pooled.__dict__}


def run(source: Path, compat: str | None, k: int = 3, n_init: int = 50, seed: int = 0, workers: int = 2,
        rate: float = 0.75) -> dict[str, Any]:
    turns = Turns.from_columns(read_turns(Path(source), compat).columns)
    parts = leave_one_person_out(turns, _one, (k, n_init, seed, rate), k, source, workers)
    return summarise(parts, rate)


def _ci(v: np.ndarray) -> list[float] | None:
    ci = evaluation.t_interval(np.asarray(v, dtype=float))
    return None if ci is None else [float(ci[0]), float(ci[1])]


def calibration(pairs: list[tuple[float, int]], bins: int = 10) -> dict[str, Any]:
    p = np.array([x for x, _ in pairs])
    y = np.array([o for _, o in pairs], dtype=float)
    edges = np.linspace(0, 1, bins + 1)
    idx = np.clip(np.digitize(p, edges) - 1, 0, bins - 1)
    rows, ece = [], 0.0
    for b in range(bins):
        sel = idx == b
        if sel.any():
            rows.append({"bin": [float(edges[b]), float(edges[b + 1])], "n": int(sel.sum()),
                         "predicted": float(p[sel].mean()), "observed": float(y[sel].mean())})
            ece += sel.sum() / len(p) * abs(p[sel].mean() - y[sel].mean())
    return {"ece": float(ece), "bins": rows}


def summarise(parts: list[dict[str, Any]], rate: float) -> dict[str, Any]:
    names = [p["session"] for p in parts]
    out: dict[str, Any] = {"sessions": len(parts), "people": len(people(names)), "rate": rate, "models": []}
    base = per_person(names, [p["ll"]["per-level"] for p in parts])
    for name in MODELS:  # means and intervals over people (a person's sessions averaged)
        v = per_person(names, [p["ll"][name] for p in parts])
        d = v - base
        out["models"].append({"model": name, "log_lik_per_turn": float(v.mean()), "log_lik_ci": _ci(v),
                              "d_per_level": float(d.mean()), "d_per_level_ci": _ci(d),
                              "calibration": calibration([x for p in parts for x in p["preds"][name]])})
    out["spans"] = [{"session": p["session"], "span": round(p["span"][0], 3),
                     "span_90": [round(p["span"][1], 3), round(p["span"][2], 3)]} for p in parts]
    out["fits"] = [{"session": p["session"], **{k: round(v, 4) for k, v in p["model"].items()}} for p in parts]
    return out


def format_summary(s: dict[str, Any]) -> str:
    lines = [f"next-turn prediction on {s['sessions']} held-out sessions of {s.get('people', '?')} people "
             "(each fitted without the session's person; intervals over people): "
             "mean log-likelihood per turn [95 % CI]; d = paired difference to per-level; ECE = calibration error"]
    for m in s["models"]:
        ci, dci = m["log_lik_ci"], m["d_per_level_ci"]
        lines.append(f"  {m['model']:<13} {m['log_lik_per_turn']:+.4f} [{ci[0]:+.4f}, {ci[1]:+.4f}]   "
                     f"d {m['d_per_level']:+.4f} [{dci[0]:+.4f}, {dci[1]:+.4f}]   ECE {m['calibration']['ece']:.3f}")
    spans = np.array([x["span"] for x in s["spans"]])
    widths = np.array([x["span_90"][1] - x["span_90"][0] for x in s["spans"]])
    lines.append(f"  span (length at {100 * s['rate']:.0f} % success) per session: median {np.median(spans):.2f}, "
                 f"range {spans.min():.2f}-{spans.max():.2f}; median 90 % interval width {np.median(widths):.2f}")
    return "\n".join(lines)
