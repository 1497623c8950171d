# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Write the mismatch findings: findings.json, report.md and PNG plots.

The report opens with one plain paragraph on what the simulation left out,
then a table of the findings (with their confidence and the held-out
residual before and after), one section per finding (its explanation,
interval, alternatives and a figure of the residual before and after it on
held-out time), the minor and weak findings, the channels, the time
alignment and what could not be judged.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np


def _clean(x):
    """Return a JSON-safe copy (NaN/inf to None, numpy to Python)."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _decimate(n: int, most: int = 4000) -> slice:
    return slice(None, None, max(1, n // most))


def _fmt_params(params: dict) -> str:
    out = []
    for k, v in params.items():
        if isinstance(v, (int, float)) and v is not None:
            out.append(f'{k} = {v:.5g}')
        elif v is None:
            out.append(f'{k} = n/a')
        else:
            out.append(f'{k} = {v}')
    return ', '.join(out)


def _held_spans(t: np.ndarray, held: np.ndarray) -> list:
    """Return [(t0, t1)] of the held-out stretches."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], held.astype(int), [0]))))
    return [(float(t[a]), float(t[min(b, t.size) - 1])) for a, b in zip(edges[::2], edges[1::2])]


def _finding_figure(plt, out: Path, name: str, t: np.ndarray, sim: np.ndarray,
                    real: np.ndarray, before: np.ndarray, after: np.ndarray, held: np.ndarray,
                    fd: dict) -> str:
    d = _decimate(t.size)
    fig, ax = plt.subplots(3, 1, figsize=(10, 6.5), sharex=True)
    ax[0].plot(t[d], sim[d], lw=0.7, label='sim')
    ax[0].plot(t[d], real[d], lw=0.7, label='real', alpha=0.8)
    ax[0].legend(fontsize=7)
    ax[0].set_title(f'{fd["channel"]}: {fd["effect"]} ({_fmt_params(fd["parameters"])})',
                    fontsize=9)
    ax[1].plot(t[d], before[d], lw=0.5, color='tab:gray', label='real - sim')
    ax[1].plot(t[d], (before - after)[d], lw=1.0, color='tab:red', label='modelled effect')
    ax[1].legend(fontsize=7)
    ax[2].plot(t[d], before[d], lw=0.4, color='tab:gray', alpha=0.6, label='before')
    ax[2].plot(t[d], after[d], lw=0.5, color='tab:blue', label='after')
    fit = fd.get('fit', {})
    hb, ha = fit.get('heldout_rmse_before'), fit.get('heldout_rmse_after')
    title = 'residual before and after; held-out time shaded'
    if hb is not None and ha is not None:
        title += f' (held-out RMSE {hb:.3g} -> {ha:.3g})'
    ax[2].set_title(title, fontsize=8)
    ax[2].legend(fontsize=7)
    ax[2].set_xlabel('t from bag start (s)')
    for a0, a1 in _held_spans(t, held):
        ax[2].axvspan(a0, a1, color='tab:green', alpha=0.08)
    if fd.get('window'):
        for a in ax:
            a.axvspan(fd['window'][0], fd['window'][1], color='tab:orange', alpha=0.15)
    fig.tight_layout()
    fig.savefig(out / name, dpi=90)
    plt.close(fig)
    return name


def _residual_figure(plt, out: Path, findings: dict, details: list) -> list:
    rows = [(d, f) for d in details for f in d.prob0.fields]
    if not rows:
        return []
    fig, axes = plt.subplots(len(rows), 1, figsize=(10, 1.6 * len(rows) + 0.6), sharex=True,
                             squeeze=False)
    for ax, (det, f) in zip(axes[:, 0], rows):
        prob = det.prob0
        dd = _decimate(prob.n)
        r = np.where(prob.mask[f], prob.r[f], np.nan)
        ax.plot(det.pt.t[dd], r[dd], lw=0.5, color='tab:gray')
        s = prob.sigma[f]
        ax.axhspan(-2 * s, 2 * s, color='tab:green', alpha=0.15)
        for w in findings['channels'].get(f'{det.pt.name}.{f}', {}).get('beyond_noise', []):
            ax.axvspan(w[0], w[1], color='tab:red', alpha=0.12)
        ax.set_ylabel(f, fontsize=7)
    axes[0, 0].set_title('residual real - sim (grey), 2-sigma noise band (green), '
                         'beyond noise (red)')
    axes[-1, 0].set_xlabel('t from bag start (s)')
    fig.tight_layout()
    fig.savefig(out / 'residuals.png', dpi=90)
    plt.close(fig)
    return ['residuals.png']


def _plots(out: Path, findings: dict, details: list) -> list:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from robot_calib.mismatch import analysis
    files = _residual_figure(plt, out, findings, details)
    k = 0
    for det in details:
        pt, prob = det.pt, det.prob
        for fd in det.time_findings:
            f = fd['channel'][len(pt.name) + 1:]
            if f not in det.prob0.fields:
                continue
            k += 1
            m = det.prob0.mask[f]
            before = np.where(m, det.prob0.r[f], np.nan)
            after = np.where(prob.mask.get(f, m), prob.r.get(f, before), np.nan)
            fd['plot'] = _finding_figure(plt, out, f'finding_{k}.png', pt.t, pt.sim[f],
                                         pt.real[f], before, after, det.held, fd)
            files.append(fd['plot'])
        for i, (t, fd) in enumerate(zip(det.sel, det.term_findings)):
            f = t.channel[len(t.topic) + 1:]
            if f not in prob.fields:
                continue
            k += 1
            m = prob.mask[f]
            before = np.where(m, prob.r[f], np.nan)
            pred = analysis._predict(prob, [t], [det.final.betas[i]], f)
            fd['plot'] = _finding_figure(plt, out, f'finding_{k}.png', pt.t, pt.sim[f],
                                         pt.real[f], before, before - pred, det.held, fd)
            files.append(fd['plot'])
    return files


def summary_paragraph(findings: dict) -> str:
    """Return one plain paragraph: what the simulation left out, and what stays unexplained."""
    named = [f for f in findings['findings'] if f['effect'] != 'unexplained']
    left = [f for f in findings['findings'] if f['effect'] == 'unexplained']
    minor = findings.get('minor_findings', [])
    if not named and not left and not minor:
        return ('The real recording follows the simulation within its noise on every compared '
                'channel: nothing is missing that this recording can show.')
    if not named and not left:
        return ('Nothing the simulation left out is large enough to matter for a ground robot. '
                'Smaller differences are significant, below the size worth naming: ' +
                '; '.join(f'{f["effect"].replace("_", " ")} on `{f["channel"]}` '
                          f'({_fmt_params(f["parameters"])})' for f in minor) + '.')
    parts = []
    for f in named:
        where = f' between {f["window"][0]:.0f} and {f["window"][1]:.0f} s' if f['window'] \
            else ''
        parts.append(f'{f["effect"].replace("_", " ")} on `{f["channel"]}` '
                     f'({_fmt_params(f["parameters"])}){where}')
    text = ''
    if parts:
        text = 'The simulation left out: ' + '; '.join(parts) + '.'
    for f in left:
        text += f' Beyond these, `{f["channel"]}` keeps an unexplained difference of ' \
            f'{f["parameters"]["rms"]:.3g} (RMS)' + (
                f' that follows {f["parameters"]["correlates_with"]}'
                if f['parameters'].get('correlates_with') not in (None, 'none') else '') + \
            ': no effect of the library accounts for it.'
    if minor:
        text += f' {len(minor)} smaller effect(s) are significant but below the size worth ' \
            'naming (listed as minor).'
    return text.strip()


def _finding_sections(findings: dict) -> list:
    lines = []
    for i, f in enumerate(findings['findings'], 1):
        lines += [f'### {i}. {f["effect"]} on `{f["channel"]}`', '', f['explanation'], '']
        if f.get('ci95'):
            ci = ', '.join(f'{k} in [{a:.4g}, {b:.4g}]' for k, (a, b) in f['ci95'].items()
                           if a is not None and b is not None)
            lines.append(f'95% interval: {ci}. Confidence {f.get("confidence", 0):.2f}.')
        for a in f.get('alternatives', []):
            lines.append(f'- alternative: {a["effect"]} on `{a["channel"]}` '
                         f'({_fmt_params(a["parameters"])}, BIC {a["delta_bic"]:+.1f}); '
                         f'{a["separating_motion"]}.')
        if f.get('plot'):
            lines += ['', f'![{f["effect"]}]({f["plot"]})']
        lines.append('')
    return lines


def _markdown(findings: dict, files: list) -> str:
    lines = ['# Sim-vs-real mismatch report', '']
    inp = findings.get('inputs', {})
    if inp:
        lines += [f'- simulated: `{inp.get("sim")}`', f'- real: `{inp.get("real")}`']
    lines += [f'- verdict: **{findings["verdict"]}**', '', summary_paragraph(findings), '']
    if findings['findings']:
        lines += ['## Findings', '', '| channel | effect | parameters | window (s) | confidence '
                  '| held-out RMSE before -> after |', '|---|---|---|---|---|---|']
        for f in findings['findings']:
            w = '-' if not f['window'] else f'{f["window"][0]:.1f} .. {f["window"][1]:.1f}'
            fit = f.get('fit') or {}
            hb, ha = fit.get('heldout_rmse_before'), fit.get('heldout_rmse_after')
            h = f'{hb:.4g} -> {ha:.4g}' if hb is not None and ha is not None else 'n/a'
            lines.append(f'| `{f["channel"]}` | {f["effect"]} | {_fmt_params(f["parameters"])} '
                         f'| {w} | {f.get("confidence", 0):.2f} | {h} |')
        lines.append('')
        lines += _finding_sections(findings)
    for key, title in (('minor_findings', 'Minor (significant, below the size worth naming)'),
                       ('weak_findings', 'Weak (not enough evidence to report)')):
        if findings.get(key):
            lines += [f'## {title}', '']
            for f in findings[key]:
                lines.append(f'- {f["effect"]} on `{f["channel"]}`: '
                             f'{_fmt_params(f["parameters"])} (confidence '
                             f'{f.get("confidence", 0):.2f})')
            lines.append('')
    lines += ['## Channels', '', '| channel | RMSE real-sim | noise | RMSE after | '
              'beyond noise (s) |', '|---|---|---|---|---|']
    for ch, c in findings['channels'].items():
        w = ', '.join(f'{a:.1f}-{b:.1f}' for a, b in c['beyond_noise']) or '-'
        lines.append(f'| `{ch}` | {c["rmse"]:.4g} | {c["noise"]:.4g} | {c["rmse_after"]:.4g} '
                     f'| {w} |')
    lines.append('')
    if 'residuals.png' in files:
        lines += ['![residuals](residuals.png)', '']
    lines += _alignment(findings)
    from robot_calib.mismatch import trajectory
    traj = findings.get('trajectory')
    lines += trajectory.markdown(traj, traj.get('plot') if traj else None)
    if findings['not_judged'] or findings['notes']:
        lines += ['## What could not be judged', '']
        for d in findings['not_judged']:
            lines.append(f'- `{d["channel"]}`: {d["reason"]}')
        for n in findings['notes']:
            lines.append(f'- {n}')
        lines.append('')
    return '\n'.join(lines)


def _alignment(findings: dict) -> list:
    ta = findings.get('time_alignment') or {}
    if not ta:
        return []
    lines = ['## Time alignment', '']
    clock = ta.get('clock')
    if clock:
        how = 'the recordings share a clock' if clock['method'] == 'stamps' else \
            f'aligned on the motion (correlation {clock["correlation"]:.2f}, ' \
            f'{clock["confidence"]:.1f} times the next best)'
        lines.append(f'- clock: real + {clock["offset"]:.3f} s = simulation time; {how}')
    for tp, v in ta.items():
        if tp == 'clock':
            continue
        if not isinstance(v, dict):
            lines.append(f'- {tp}: {v}')
            continue
        text = f'- `{tp}`: cross-correlation peak at {v.get("xcorr_lag", 0) * 1000:.1f} ms'
        for d in v.get('delays', []):
            text += f'; {d["effect"]} {d["tau"] * 1000:.2f} +- {d["std"] * 1000:.2f} ms'
        lines.append(text)
    lines.append('')
    return lines


def write(out: Path, findings: dict, details: list, plots: bool = True) -> None:
    """Write findings.json, report.md and (optionally) the PNG plots into ``out``."""
    files = _plots(out, findings, details) if plots else []
    findings['summary'] = summary_paragraph(findings)
    clean = _clean(findings)
    (out / 'findings.json').write_text(json.dumps(clean, indent=2) + '\n')
    (out / 'report.md').write_text(_markdown(clean, files) + '\n')
