"""Forward simulation of the indentation test: from mesh, law, parameters and load
history to a self-contained xarray Dataset (`u(time, node, component)`, indenter depth and
force, the mesh itself, provenance)."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from .fem.biphasic import DRAINED_DEFAULT, Biphasic, febio8_space
from .fem.indentation import Indentation
from .fem.solver import NewtonOptions, solve_history
from .fem.space import Space
from .fileio import file_sha256, provenance
from .laws import get_law
from .loading import LoadHistory
from .mesh import TetMesh, read_mesh

__all__ = ["ForwardModel", "Inclusion", "read_inclusions", "simulate"]

log = logging.getLogger(__name__)


class ForwardModel:
    """A mesh and its discrete space, built once and reused for many parameter sets.

    Parameters
    ----------
    mesh : path or TetMesh
    punch : "frictionless" or "bonded"
    support : "fixed" or "sliding" (a law with the bottom_slip term makes a fixed bottom compliant)
    quadrature_order : polynomial degree the tetrahedron rule integrates exactly (2: the
        4-point rule of the peer references; 5: 14 points, more robust for neo-Hookean
        laws near the punch rim)
    drained : mesh groups with free draining (p = 0) for biphasic laws; other faces are
        impermeable
    inclusions : spheres of other material, `Inclusion` or dicts ``{center_m, radius_m,
        scale: {param: factor}}``: the listed parameters of the elements whose centroid lies
        inside are multiplied by their factors (after `region_params`)

    Biphasic laws integrate with at least 8 points: FEBio's 8-point rule replaces the
    4- or 5-point rules (orders 2, 3), on which the u-p model fails near undrained states.
    """

    def __init__(self, mesh, punch="frictionless", support="fixed", quadrature_order=2,
                 drained=DRAINED_DEFAULT, inclusions=()):
        self.mesh = mesh if isinstance(mesh, TetMesh) else read_mesh(mesh)
        self.inclusions = [Inclusion.of(i) for i in inclusions]
        self.space = Space(self.mesh, intorder=quadrature_order)
        self.quadrature_order = quadrature_order
        self.punch, self.support = punch, support
        self.drained = tuple(drained)
        self.mesh_sha256 = file_sha256(self.mesh.path) if self.mesh.path else "in-memory"
        self._space_biphasic = None

    def element_params(self, law_name, params, region_params=None) -> dict:
        """Full parameter set of a law; `region_params` maps a region id (gmsh physical tag
        of the volume) to overrides for the elements of that region; the inclusions scale
        their elements' values."""
        law = get_law(law_name)
        full = law.resolve(params)
        fitted = [inc for inc in self.inclusions if inc.fitted]
        if "inc_scale" in law.free and len(fitted) != 1:
            raise ValueError(f"law {law_name!r} fits the contrast of one inclusion; the model has {len(fitted)} "
                             "inclusions with scale 'fitted' (--inclusions)")
        if not region_params and not self.inclusions:
            return full
        out = {k: np.full(self.mesh.n_elements, v, dtype=float) for k, v in full.items()}
        for region, over in (region_params or {}).items():
            sel = self.mesh.cell_region == int(region)
            if not sel.any():
                raise ValueError(f"region {region} has no elements; regions: {sorted(set(self.mesh.cell_region))}")
            merged = law.resolve({**{k: full[k] for k in law.free}, **over})
            for k in law.free:
                out[k][sel] = merged[k]
        for inc in self.inclusions:
            sel = inc.elements(self.mesh)
            scale = {"C1": full["inc_scale"], "C2": full["inc_scale"]} if inc.fitted else inc.scale
            for k, f in scale.items():
                if k not in out:
                    raise ValueError(f"inclusion scales {k!r}, which is not a parameter")
                out[k][sel] *= f
        return out

    def model(self, law_name, params, region_params=None, compliant_bottom=False) -> Indentation | Biphasic:
        """The model of a law at `params`. A law with the ``bottom_slip`` term (``c_bottom``),
        or `compliant_bottom`, puts a tangential spring on a fixed bottom instead of fixing
        u_x, u_y there (at c_bottom = 0 the same to about 1e-6)."""
        law = get_law(law_name)
        support = self.support
        if compliant_bottom or "c_bottom" in law.free:
            if self.support != "fixed":
                raise ValueError(f"bottom slip is a compliance of a fixed bottom; this model's support is {self.support!r}")
            support = "compliant"
        if "k_punch" in law.free and self.punch != "frictionless":
            raise ValueError(f"punch friction is a spring on a frictionless punch; this model's punch is {self.punch!r}")
        if law.biphasic:
            return Biphasic(self.biphasic_space(), self.element_params(law_name, params, region_params),
                            punch=self.punch, support=support, drained=self.drained)
        return Indentation(self.space, self.element_params(law_name, params, region_params),
                           punch=self.punch, support=support)

    def biphasic_space(self) -> Space:
        """The space of biphasic laws: FEBio's 8-point rule unless the configured rule has
        at least 8 points."""
        if self.space.nq >= 8:
            return self.space
        if self._space_biphasic is None:
            self._space_biphasic = febio8_space(self.mesh)
        return self._space_biphasic

    def run(self, law_name, params, history: LoadHistory, options: NewtonOptions | None = None,
            region_params=None, attrs=None) -> xr.Dataset:
        model = self.model(law_name, params, region_params)
        record = _BiphasicRecord(model, len(history.time)) if isinstance(model, Biphasic) else None
        h = solve_history(model, history.time, history.value, history.control, options, record)
        if record is not None:
            h.p, h.fluid_load_fraction = record.p, record.fluid_fraction(h.force)
            h.p_nodes = model.p_nodes
        h.quadrature_points = int(model.space.nq)
        law = get_law(law_name)
        resolved = law.resolve(params)
        return self.to_dataset(h, law_name, {k: resolved[k] for k in law.free} | dict(law.fixed),
                               history, region_params, attrs)

    def to_dataset(self, h, law_name, params, history, region_params=None, attrs=None) -> xr.Dataset:
        m = self.mesh
        ds = xr.Dataset(
            data_vars=dict(
                indenter_depth=("time", h.depth, {"units": "m", "long_name": "punch depth, positive into the tissue"}),
                indenter_force=("time", h.force, {"units": "N", "long_name": "punch force, positive compressive"}),
                u=(("time", "node", "component"), h.u, {"units": "m", "long_name": "nodal displacement"}),
                X=(("node", "component"), m.points, {"units": "m", "long_name": "reference node coordinates"}),
                cells=(("element", "local"), m.cells, {"long_name": "tet10 connectivity (meshio/VTK order)"}),
                cell_region=("element", m.cell_region, {"long_name": "region id (gmsh physical tag)"}),
                newton_iterations=("time", h.iterations, {"long_name": "nonlinear iterations to reach the frame"}),
                step_cuts=("time", h.cuts, {"long_name": "automatic step cuts on the way to the frame"}),
            ),
            coords=dict(time=("time", h.time, {"units": "s"}), component=["x", "y", "z"]),
        )
        if getattr(h, "p", None) is not None:
            ds["p"] = (("time", "pnode"), h.p, {"units": "Pa", "long_name": "pore pressure at the corner nodes"})
            ds = ds.assign_coords(pnode=("pnode", h.p_nodes, {"long_name": "mesh node of each pressure value"}))
            ds["fluid_load_fraction"] = ("time", h.fluid_load_fraction, {
                "units": "1", "long_name": "share of the indenter force carried by the pore pressure"})
        ds.attrs = provenance(
            law=law_name, params=params, region_params=region_params or {},
            control=history.control, punch=self.punch, support=self.support,
            inclusions=[i.to_json() for i in self.inclusions],
            quadrature_points=int(getattr(h, "quadrature_points", self.space.nq)),
            **({"drained": list(self.drained)} if getattr(h, "p", None) is not None else {}),
            mesh=str(m.path) if m.path else "in-memory", mesh_sha256=self.mesh_sha256,
            solver=dict(h.timing), **(attrs or {}))
        return ds


@dataclass(frozen=True)
class Inclusion:
    """A sphere of other material (centre and radius in m; parameter -> factor, or "fitted":
    C1 and C2 scaled by the law's parameter inc_scale)."""
    center_m: tuple
    radius_m: float
    scale: dict | str

    @property
    def fitted(self) -> bool:
        return self.scale == "fitted"

    @classmethod
    def of(cls, spec) -> "Inclusion":
        if isinstance(spec, cls):
            return spec
        c = tuple(float(v) for v in spec["center_m"])
        r = float(spec["radius_m"])
        if spec["scale"] == "fitted":
            if len(c) != 3 or not r > 0:
                raise ValueError(f"inclusion {spec}: needs center_m [x, y, z] and radius_m > 0")
            return cls(c, r, "fitted")
        scale = {str(k): float(v) for k, v in dict(spec["scale"]).items()}
        if len(c) != 3 or not r > 0 or not scale or min(scale.values()) <= 0:
            raise ValueError(f"inclusion {spec}: needs center_m [x, y, z], radius_m > 0 and positive scale factors")
        return cls(c, r, scale)

    def elements(self, mesh) -> np.ndarray:
        """Elements whose centroid (of the corner nodes) lies inside the sphere."""
        centroid = mesh.points[mesh.cells[:, :4]].mean(axis=1)
        return np.linalg.norm(centroid - np.asarray(self.center_m), axis=1) < self.radius_m

    def to_json(self) -> dict:
        return {"center_m": list(self.center_m), "radius_m": self.radius_m,
                "scale": self.scale if self.fitted else dict(self.scale)}


def read_inclusions(text) -> list:
    """Inclusions from JSON/YAML text or a file holding a list of ``{center_m, radius_m, scale}``
    (or a mapping with that list under ``inclusions``)."""
    import yaml
    if not text:
        return []
    path = Path(str(text))
    spec = yaml.safe_load(path.read_text() if path.is_file() else str(text))
    if isinstance(spec, dict):
        spec = spec.get("inclusions", [spec])
    return [Inclusion.of(i) for i in spec]


class _BiphasicRecord:
    """Pore pressure and fluid force on the punch at every frame of a biphasic run."""

    def __init__(self, model: Biphasic, n):
        self.model = model
        self.p = np.zeros((n, len(model.p_nodes)))
        self.fluid = np.zeros(n)

    def __call__(self, k, q, ev):
        self.p[k] = self.model.pressure(q)
        self.fluid[k] = self.model.fluid_force(q)

    def fluid_fraction(self, force):
        """Fluid force / indenter force; NaN where the indenter force is ~0."""
        ok = np.abs(force) > 1e-6 * max(np.abs(force).max(), 1e-30)
        return np.where(ok, self.fluid / np.where(ok, force, 1.0), np.nan)


def simulate(mesh, law, params, history: LoadHistory, punch="frictionless", support="fixed",
             options: NewtonOptions | None = None, region_params=None) -> xr.Dataset:
    """One forward run; see `ForwardModel.run`."""
    return ForwardModel(mesh, punch, support).run(law, params, history, options, region_params)


def force_history_of(ds: xr.Dataset) -> LoadHistory:
    """The force history of a run, to drive a force-controlled run."""
    return LoadHistory("force", ds.time.values.copy(), ds.indenter_force.values.copy())


def load_params(ds: xr.Dataset) -> dict:
    return json.loads(ds.attrs["params"])
