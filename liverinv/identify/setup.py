"""An objective from files: the bundle's indenter record, the tracked flow, the meshes and
the objective's options, checked, as `liverinv fit` and `liverinv diagnose` build it."""

from __future__ import annotations

from pathlib import Path

from ..errors import UserError

__all__ = ["objective_from_files", "MIN_CONFIDENT_NODES"]

MIN_CONFIDENT_NODES = 10   # fewer confident tracked nodes give no volumetric term worth the name


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
            tracking_mesh = mesh if model_mesh else fm.mesh   # read once if the same
            obs = tracking_observation(b, fl, tracking_mesh, fm.mesh)
        noise = None
        if objective == "likelihood":
            from .noise import noise_model
            noise = noise_model(ind, fl, noise_force, noise_depth, noise_tracking)
        obj = Objective(fm, law, Measurements.from_flow(fl, ind.time_s, ind.displacement_m, ind.force_N),
                        fixed=fixed, observation=obs, noise=noise)
    return obj, observation
