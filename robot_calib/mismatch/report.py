# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Write the mismatch findings: findings.json, report.md and PNG plots.

Per finding one figure: the channel (sim and real), the residual with the
fitted effect and its window shaded, and the residual after the effect is
applied. One overview figure shows every channel's residual with its noise
band and the windows where it is beyond noise.
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


def _plots(out: Path, findings: dict, details: list) -> list:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from robot_calib.mismatch import analysis
    files = []
    rows = [(pt, prob, f) for pt, prob, _, _ in details for f in prob.fields]
    if rows:
        fig, axes = plt.subplots(len(rows), 1, figsize=(10, 1.6 * len(rows) + 0.6),
                                 sharex=True, squeeze=False)
        for ax, (pt, prob, f) in zip(axes[:, 0], rows):
            d = _decimate(prob.n)
            r = np.where(prob.mask[f], prob.r[f], np.nan)
            ax.plot(pt.t[d], r[d], lw=0.5, color='tab:gray')
            s = prob.sigma[f]
            ax.axhspan(-2 * s, 2 * s, color='tab:green', alpha=0.15)
            ch = f'{pt.name}.{f}'
            for w in findings['channels'].get(ch, {}).get('beyond_noise', []):
                ax.axvspan(w[0], w[1], color='tab:red', alpha=0.12)
            ax.set_ylabel(f, fontsize=7)
        axes[0, 0].set_title('residual real - sim (grey), 2-sigma noise band (green), '
                             'beyond noise (red)')
        axes[-1, 0].set_xlabel('t from bag start (s)')
        fig.tight_layout()
        fig.savefig(out / 'residuals.png', dpi=90)
        plt.close(fig)
        files.append('residuals.png')
    k = 0
    for pt, prob, sel, fs in details:
        fit = None
        for i, (t, fd) in enumerate(zip(sel, fs)):
            if fit is None:
                from robot_calib.mismatch import select as S
                fit = S.fit(prob, sel, contributions=True)
            f = t.channel[len(t.topic) + 1:]
            if f not in prob.fields:
                continue
            k += 1
            m = prob.mask[f]
            d = _decimate(prob.n)
            pred = analysis._predict(prob, [t], [fit.betas[i]], f)
            r = np.where(m, prob.r[f], np.nan)
            fig, ax = plt.subplots(3, 1, figsize=(10, 6.5), sharex=True)
            ax[0].plot(pt.t[d], pt.sim[f][d], lw=0.7, label='sim')
            ax[0].plot(pt.t[d], pt.real[f][d], lw=0.7, label='real', alpha=0.8)
            ax[0].legend(fontsize=7)
            pars = ', '.join(f'{k} = {v:.4g}' for k, v in fd['parameters'].items())
            ax[0].set_title(f'{fd["channel"]}: {fd["effect"]} ({pars})', fontsize=9)
            ax[1].plot(pt.t[d], r[d], lw=0.5, color='tab:gray', label='real - sim')
            ax[1].plot(pt.t[d], pred[d], lw=1.0, color='tab:red', label='fitted effect')
            ax[1].legend(fontsize=7)
            ax[2].plot(pt.t[d], (r - fit.contrib.get(f, 0.0))[d], lw=0.5, color='tab:blue',
                       label='residual after all effects')
            ax[2].legend(fontsize=7)
            ax[2].set_xlabel('t from bag start (s)')
            if fd['window']:
                for a in ax:
                    a.axvspan(fd['window'][0], fd['window'][1], color='tab:orange', alpha=0.15)
            fig.tight_layout()
            name = f'finding_{k}.png'
            fig.savefig(out / name, dpi=90)
            plt.close(fig)
            fd['plot'] = name
            files.append(name)
    return files


def _markdown(findings: dict, files: list) -> str:
    lines = ['# Sim-vs-real mismatch report', '']
    inp = findings.get('inputs', {})
    if inp:
        lines += [f'- simulated: `{inp.get("sim")}`', f'- real: `{inp.get("real")}`']
    lines += [f'- verdict: **{findings["verdict"]}**', '']
    if findings['findings']:
        lines += ['## Findings', '', '| channel | effect | parameters | window (s) | '
                  'held-out RMSE before -> after |', '|---|---|---|---|---|']
        for f in findings['findings']:
            p = ', '.join(f'{k} = {v:.5g}' for k, v in f['parameters'].items())
            w = '-' if not f['window'] else f'{f["window"][0]:.1f} .. {f["window"][1]:.1f}'
            fit = f['fit']
            hb, ha = fit.get('heldout_rmse_before'), fit.get('heldout_rmse_after')
            h = f'{hb:.4g} -> {ha:.4g}' if hb is not None and ha is not None else 'n/a'
            lines.append(f'| `{f["channel"]}` | {f["effect"]} | {p} | {w} | {h} |')
        lines.append('')
        for i, f in enumerate(findings['findings'], 1):
            lines += [f'### {i}. {f["effect"]} on `{f["channel"]}`', '', f['explanation'], '']
            ci = ', '.join(f'{k} in [{a:.4g}, {b:.4g}]' for k, (a, b) in f['ci95'].items())
            lines.append(f'95% interval: {ci}.')
            for a in f.get('alternatives', []):
                lines.append(f'- alternative: {a["effect"]} on `{a["channel"]}` '
                             f'{a["parameters"]} (BIC {a["delta_bic"]:+.1f}); '
                             f'{a["separating_motion"]}.')
            if f.get('plot'):
                lines += ['', f'![{f["effect"]}]({f["plot"]})']
            lines.append('')
    else:
        lines += ['Every compared channel is explained by noise: no effect is reported.', '']
    lines += ['## Channels', '', '| channel | RMSE real-sim | noise | RMSE after | '
              'beyond noise (s) |', '|---|---|---|---|---|']
    for ch, c in findings['channels'].items():
        w = ', '.join(f'{a:.1f}-{b:.1f}' for a, b in c['beyond_noise']) or '-'
        lines.append(f'| `{ch}` | {c["rmse"]:.4g} | {c["noise"]:.4g} | {c["rmse_after"]:.4g} '
                     f'| {w} |')
    lines.append('')
    if 'residuals.png' in files:
        lines += ['![residuals](residuals.png)', '']
    if findings['time_alignment']:
        lines += ['## Time alignment', '']
        for tp, v in findings['time_alignment'].items():
            lines.append(f'- `{tp}`: cross-correlation peak at {v["xcorr_lag"] * 1000:.1f} ms')
        lines.append('')
    if findings['not_judged'] or findings['notes']:
        lines += ['## What could not be judged', '']
        for d in findings['not_judged']:
            lines.append(f'- `{d["channel"]}`: {d["reason"]}')
        for n in findings['notes']:
            lines.append(f'- {n}')
        lines.append('')
    return '\n'.join(lines)


def write(out: Path, findings: dict, details: list, plots: bool = True) -> None:
    """Write findings.json, report.md and (optionally) the PNG plots into ``out``."""
    files = _plots(out, findings, details) if plots else []
    clean = _clean(findings)
    (out / 'findings.json').write_text(json.dumps(clean, indent=2) + '\n')
    (out / 'report.md').write_text(_markdown(clean, files) + '\n')
