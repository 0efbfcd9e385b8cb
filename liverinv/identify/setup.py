"""An objective from files: the bundle's indenter record, the tracked flow, the meshes and
the objective's options, checked, as `liverinv fit` and `liverinv diagnose` build it."""

from __future__ import annotations

from pathlib import Path

from ..errors import UserError

__all__ = ["objective_from_files", "MIN_CONFIDENT_NODES"]

MIN_CONFIDENT_NODES = 10   # fewer confident tracked nodes give no volumetric term worth the name


#: observation operators kept for the next objective on the same files: `discover` builds an
#: objective for every trial, swap and step (its base fit, the trials, the final fit on the finer
#: mesh), and each operator took 8-10 s to build on the coarse benchmark mesh (1490 x 1490 nodes)
OBSERVATIONS_KEPT = 2
_OBSERVATIONS: dict = {}


def _observation_key(*paths):
    """The files' identity: resolved path, size and modification time of each."""
    out = []
    for p in paths:
        st = Path(p).stat()
        out.append((str(Path(p).resolve()), st.st_size, st.st_mtime_ns))
    return tuple(out)


def objective_from_files(bundle, flow, mesh, law, fixed=None, model_mesh=None, objective="likelihood",
                         observation=None, noise_force=None, noise_depth=None, noise_tracking=None,
                         quadrature_order=2, indenter_only=False, inclusions=()):
    """(Objective, observation name) for one law on a bundle and its flow; UserError naming
    the file for inputs that do not fit together."""
    import xarray as xr

    from ..forward import ForwardModel
    from ..imaging.bundle import open_bundle
    from ..imaging.observation import tracking_observation
    from .objective import Measurements, Objective

    if observation is None:
        observation = "tracker" if objective == "likelihood" else "nodes"
    for path, what in ((bundle, "bundle"), (flow, "flow")):
        if not Path(path).is_file():
            raise UserError(f"{path}: {what} file not found")
    with xr.open_dataset(flow, engine="h5netcdf") as fl:
        fl = fl.load()
    if "u_of" not in fl or "c_of" not in fl:
        raise UserError(f"{flow}: not a flow file (liverinv track writes one); it has no u_of/c_of")
    n_conf = int((fl.c_of.values.min(axis=(0, 2)) > 0).sum())
    if n_conf < MIN_CONFIDENT_NODES and not indenter_only:
        raise UserError(f"{flow}: only {n_conf} tracked nodes have confidence > 0 (need "
                        f"{MIN_CONFIDENT_NODES}): the mesh may lie outside the images or the volumes have no "
                        "texture (see liverinv check); --indenter-only fits the indenter record alone")
    if indenter_only:
        fl["c_of"] = fl.c_of * 0.0
    fm = ForwardModel(model_mesh or mesh, quadrature_order=quadrature_order, inclusions=inclusions)
    if not model_mesh and fl.sizes.get("node") != fm.mesh.n_nodes:
        raise UserError(f"{flow} has {fl.sizes.get('node')} nodes, {mesh} {fm.mesh.n_nodes}: was it tracked on "
                        "this mesh?")
    with open_bundle(bundle) as b:
        ind = b.indenter
        obs = None
        if observation == "tracker":
            key = _observation_key(bundle, flow, mesh, model_mesh or mesh)
            obs = _OBSERVATIONS.pop(key, None)
            if obs is None:
                tracking_mesh = mesh if model_mesh else fm.mesh   # read once if the same
                obs = tracking_observation(b, fl, tracking_mesh, fm.mesh)
            _OBSERVATIONS[key] = obs                          # the latest last
            while len(_OBSERVATIONS) > OBSERVATIONS_KEPT:
                _OBSERVATIONS.pop(next(iter(_OBSERVATIONS)))
        noise = None
        if objective == "likelihood":
            from .noise import noise_model
            noise = noise_model(ind, fl, noise_force, noise_depth, noise_tracking)
        obj = Objective(fm, law, Measurements.from_flow(fl, ind.time_s, ind.displacement_m, ind.force_N),
                        fixed=fixed, observation=obs, noise=noise)
    return obj, observation
