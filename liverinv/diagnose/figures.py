"""Diagnosis figures: the candidates' predicted drops with their p-values; the discovery's
error falling step by step."""

from __future__ import annotations

import numpy as np

from ..pipeline.figures import _plt, _save


def plot_diagnosis(ds, out):
    plt = _plt()
    splits = [v for v in ds.data_vars if v.startswith("share_")]
    rows = 2 if len(splits) > 4 else 1
    cols = -(-len(splits) // rows)
    fig = plt.figure(figsize=(7 + 3.2 * cols, 3.5 * rows))
    grid = fig.add_gridspec(rows, 1 + cols, width_ratios=[2.2] + [1] * cols)
    ax = fig.add_subplot(grid[:, 0])
    for j, v in enumerate(splits):
        a = fig.add_subplot(grid[j // cols, 1 + j % cols])
        dim = ds[v].dims[0]
        a.bar(range(ds.sizes[dim]), 100 * ds[v].values, color="tab:blue")
        a.set_xticks(range(ds.sizes[dim]), ds[dim].values, rotation=20, fontsize=8)
        of = ds[v].attrs.get("long_name", "share of Phi_vol").split(" by ")[0]
        a.set(ylabel=f"{of} (%)" if len(of) < 20 else "share (%)", title=f"misfit by {dim.replace('_', ' ')}" if "Phi_vol" in of else
              f"{'residual' if dim == 'gradient' else 'tracked'} velocity gradient")
    y = np.arange(ds.sizes["effect"])
    ax.barh(y, 100 * ds.predicted_drop.values, color=["tab:green" if e == ds.attrs["recommended"] else "0.6"
                                                       for e in ds.effect.values])
    for yi, p in zip(y, ds.p_value.values):
        ax.text(0.5, yi, f"p = {p:.2g}", va="center", fontsize=8)
    ax.set_yticks(y, ds.effect.values)
    ax.invert_yaxis()
    ax.set(xlabel="predicted drop of Phi (% of Phi_vol)", title=f"recommended: {ds.attrs['recommended']}")
    fig.tight_layout()
    return _save(fig, out)


def plot_discovery(ds, out):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.8))
    x = ds.step.values
    labels = ["base " + str(ds.law.values[0])] + [f"+ {a}" for a in ds.added.values[1:]]
    ax.plot(x, ds.phi_vol.values, "o-", label="Phi_vol")
    ax.plot(x, ds.phi_ind.values, "s--", label="Phi_ind")
    ax.set_xticks(x, labels, rotation=15)
    ax.set(yscale="log", ylabel="misfit (dimensionless, common noise levels)", title="discovery")
    ax.legend()
    fig.tight_layout()
    return _save(fig, out)
