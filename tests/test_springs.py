"""Punch friction and bottom slip as tangential springs: their limits are the frictionless,
bonded, fixed and sliding models; their sensitivities at the null match differences of
whole solves; laws compose with them by name."""

import numpy as np
import pytest

from liverinv.diagnose.effects import law_with
from liverinv.fem.sensitivity import Sensitivity
from liverinv.fem.solver import solve_history
from liverinv.fem.springs import tri6_mass
from liverinv.forward import ForwardModel
from liverinv.laws import LawError, get_law
from liverinv.loading import ramp_history

E = dict(C1=200.0, C2=5000.0, D1=1.5e-3)


@pytest.fixture(scope="module")
def mesh(tmp_path_factory):
    from liverinv.meshgen import generate_indentation_mesh
    return generate_indentation_mesh(tmp_path_factory.mktemp("m") / "tiny.msh", h_far=0.03, h_rim=0.004)


def force(mesh, law, params, **contact):
    fm = ForwardModel(mesh, **contact)
    h = ramp_history(3e-3, 2e-3, frames=5, unload=False)
    return solve_history(fm.model(law, params), h.time, h.value, "displacement").force[-1]


def test_face_mass_integrates_area_and_first_moments(mesh):
    """1' M 1 is the face area (Heron's formula per triangle) and 1' M x = int x dA (the
    area-weighted centroids), on the footprint and the bottom."""
    from liverinv.mesh import read_mesh
    m = read_mesh(mesh)
    for group in ("footprint", "bottom"):
        tri = m.facets[group]
        M = tri6_mass(m.points, tri)
        c = m.points[tri[:, :3]]
        a, b, e = (np.linalg.norm(c[:, i] - c[:, j], axis=1) for i, j in ((0, 1), (1, 2), (2, 0)))
        s = (a + b + e) / 2
        heron = np.sqrt(s * (s - a) * (s - b) * (s - e))
        assert M.sum(axis=(1, 2)) == pytest.approx(heron, rel=1e-10)
        f = c[..., 0] + 2.0 * c[..., 1]                 # a linear field at the corners,
        x = np.concatenate([f, (f + np.roll(f, -1, axis=1)) / 2], axis=1)   # and at the edge midpoints
        assert np.einsum("fab,fb->f", M, x) == pytest.approx(heron * f.mean(axis=1),
                                                            rel=1e-9, abs=1e-16)


def test_spring_limits_are_the_contact_models(mesh):
    """Measured on the tiny mesh at 3 mm: fixed vs compliant at c_bottom 0 5e-9, sliding vs
    c_bottom 1e-2 m/Pa 1.6e-4, bonded vs k_punch 1e12 Pa/m 3e-6 (relative force)."""
    fixed = force(mesh, "elastic", E)
    assert force(mesh, "elastic+punch_friction", dict(E, k_punch=0.0)) == fixed
    assert force(mesh, "elastic+bottom_slip", dict(E, c_bottom=0.0)) == pytest.approx(fixed, rel=1e-6)
    bonded = force(mesh, "elastic", E, punch="bonded")
    sliding = force(mesh, "elastic", E, support="sliding")
    assert bonded > 1.2 * fixed and sliding < 0.95 * fixed       # the limits differ from the base
    assert force(mesh, "elastic+punch_friction", dict(E, k_punch=1e12)) == pytest.approx(bonded, rel=2e-5)
    assert force(mesh, "elastic+bottom_slip", dict(E, c_bottom=1e-2)) == pytest.approx(sliding, rel=1e-3)
    mid = force(mesh, "elastic+punch_friction", dict(E, k_punch=1e6))
    assert fixed < mid < bonded


def test_a_sliding_bottom_does_not_turn_the_body(coarse_mesh):
    """A sliding bottom holds the body's rigid in-plane motion without moving it: on the coarse
    benchmark mesh (no bottom node on the axis) at 3 mm, the rigid translation and rotation
    fitted to the tangential motion of the bottom's nodes (u_theta = w r - a sin(theta) + b
    cos(theta); an axisymmetric motion has none) are 1.0e-3 and 9e-5 (w R) of its largest radial
    motion (pinning the node nearest the axis, 2.6 mm off it, made them 0.17 and 0.17), and the
    motion is the one of a 100 times softer spring to 0.9 um (the bottom-slip term's sliding
    end). With pins on the axis (a column mesh with a corner there) see test_biphasic's undrained
    compression, exact to 1e-7."""
    from liverinv.fem.boundary import C_SLIDING, sliding_pins
    from liverinv.fem.indentation import Indentation
    assert sliding_pins(coarse_mesh) is None
    fm = ForwardModel(coarse_mesh, support="sliding")
    h = ramp_history(3e-3, 2e-3, frames=5, unload=False)
    u = fm.run("elastic", E, h).u.values[-1]
    bottom = coarse_mesh.nodes("bottom")
    X, ub = coarse_mesh.points[bottom, :2], u[bottom, :2]
    r = np.hypot(X[:, 0], X[:, 1])
    cos, sin = X[:, 0] / r, X[:, 1] / r
    u_r = np.abs(ub[:, 0] * cos + ub[:, 1] * sin).max()
    u_theta = ub[:, 1] * cos - ub[:, 0] * sin
    (a, b, w), *_ = np.linalg.lstsq(np.column_stack([-sin, cos, r]), u_theta, rcond=None)
    assert np.hypot(a, b) < 1e-2 * u_r and abs(w) * r.max() < 1e-2 * u_r
    softer = Indentation(fm.space, dict(get_law("elastic").resolve(E), c_bottom=100 * C_SLIDING), support="compliant")
    u_softer = solve_history(softer, h.time, h.value, "displacement").u[-1]
    assert np.abs(u - u_softer).max() < 2e-6


def test_biphasic_spring_limits_are_the_contact_models(mesh):
    """The same springs on the biphasic model (kappa 1e-8, 3 mm at 2 mm/s): at their nulls
    the frictionless / fixed model, stiff the bonded / sliding one. Measured: compliant at
    c_bottom 0 2e-8, bonded 1.216 and sliding 0.832 of the fixed force, k_punch 1e12 2.4e-6
    from bonded, c_bottom 1e-2 3.0e-4 from sliding."""
    PE = dict(E, kappa=1e-8)
    fixed = force(mesh, "PE", PE)
    assert force(mesh, "PE+punch_friction", dict(PE, k_punch=0.0)) == fixed
    assert force(mesh, "PE+bottom_slip", dict(PE, c_bottom=0.0)) == pytest.approx(fixed, rel=1e-6)
    bonded = force(mesh, "PE", PE, punch="bonded")
    sliding = force(mesh, "PE", PE, support="sliding")
    assert bonded > 1.15 * fixed and sliding < 0.9 * fixed
    assert force(mesh, "PE+punch_friction", dict(PE, k_punch=1e12)) == pytest.approx(bonded, rel=2e-5)
    assert force(mesh, "PE+bottom_slip", dict(PE, c_bottom=1e-2)) == pytest.approx(sliding, rel=1e-3)


@pytest.mark.parametrize("name, law, step", [("k_punch", "elastic+punch_friction", 1e3),
                                             ("c_bottom", "elastic+bottom_slip", 1e-9),
                                             ("k_punch", "PE+punch_friction", 1e3),
                                             ("c_bottom", "PE+bottom_slip", 1e-9)])
def test_sensitivity_at_the_null_matches_differences_of_solves(mesh, name, law, step):
    """d u / d(amplitude) at the null (0) against a Richardson forward difference
    (amplitudes h and 2h) of whole solves, on the solid and on the biphasic model
    (kappa 1e-8: the generic sensitivity step)."""
    fm = ForwardModel(mesh)
    hist = ramp_history(3e-3, 2e-3, frames=5, unload=True)
    base = dict(E, kappa=1e-8) if get_law(law).biphasic else E
    null = dict(base, **{name: 0.0})
    model = fm.model(law, null)
    u = lambda a: solve_history(fm.model(law, dict(base, **{name: a})), hist.time, hist.value, "displacement").u
    u0, u1, u2 = u(0.0), u(step), u(2 * step)
    fd = (4 * (u1 - u0) - (u2 - u0)) / (2 * step)
    eps = step * 1e-6
    sens = Sensitivity([model.with_params(fm.element_params(law, dict(base, **{name: eps})))], eps)
    h = solve_history(model, hist.time, hist.value, "displacement", sensitivity=sens)
    assert np.abs(fd).max() > 1e-3 * np.abs(u1 - u0).max() / step
    assert np.abs(h.du[:, 0] - fd).max() < 2e-3 * np.abs(fd).max()


def test_laws_compose_with_boundary_terms():
    law = get_law("SR+punch_friction")
    assert law.free == get_law("SR").free + ("k_punch",)
    assert law.resolve(dict(law.defaults))["c_bottom"] == 0.0
    assert get_law("elastic+punch_friction+bottom_slip").free[-2:] == ("k_punch", "c_bottom")
    assert get_law("PE+bottom_slip").free == get_law("PE").free + ("c_bottom",)
    for bad in ["SR+friction", "SR+punch_friction+punch_friction", "nope+bottom_slip"]:
        with pytest.raises(LawError):
            get_law(bad)
    assert law_with("SR", ["punch_friction"]) == ("SR+punch_friction", {})
    assert law_with("elastic", ["shear_relaxation", "bottom_slip"]) == ("SR+bottom_slip", {})
    assert law_with("elastic+bottom_slip", ["punch_friction"]) == ("elastic+punch_friction+bottom_slip", {})
    assert law_with("elastic+bottom_slip", ["poroelastic"]) == ("PE+bottom_slip", {})


def test_bad_contact_combinations_are_refused(mesh):
    with pytest.raises(ValueError, match="frictionless punch"):
        ForwardModel(mesh, punch="bonded").model("elastic+punch_friction", dict(E, k_punch=1e5))
    with pytest.raises(ValueError, match="fixed bottom"):
        ForwardModel(mesh, support="sliding").model("elastic+bottom_slip", dict(E, c_bottom=1e-6))


def test_both_models_hold_the_same_components(mesh):
    """One definition of the boundary conditions: the displacement numbering of the
    indentation and biphasic models agrees for every contact and support, with the counts
    each condition implies (a bonded footprint holds 2 more components per footprint node, a
    fixed bottom 2 more per bottom node than a compliant one, a sliding bottom 3 in all more
    than a compliant one where it is pinned, none where a spring holds it), and a name that is
    not a choice is refused by both."""
    from liverinv.fem.biphasic import Biphasic
    from liverinv.fem.boundary import constrained_components, sliding_pins
    from liverinv.fem.indentation import Indentation
    from liverinv.fem.space import Space
    from liverinv.mesh import read_mesh
    m = read_mesh(mesh)
    space = Space(m)
    n_foot, n_bottom = len(m.nodes("footprint")), len(m.nodes("bottom"))
    n_free = {}
    for punch in ("frictionless", "bonded"):
        for support in ("fixed", "sliding", "compliant"):
            a = Indentation(space, get_law("elastic").resolve(E), punch, support)
            b = Biphasic(space, dict(E, kappa=1e-8), punch, support)
            assert a.n_free == b.n_free
            np.testing.assert_array_equal(a.asm.index, b.asm.index[:3 * m.n_nodes])
            fixed, tied = constrained_components(m, punch, support)
            assert tied.sum() == n_foot and not (fixed & tied).any()
            n_free[punch, support] = a.n_free
    for support in ("fixed", "sliding", "compliant"):
        assert n_free["frictionless", support] - n_free["bonded", support] == 2 * n_foot
    assert n_free["bonded", "compliant"] - n_free["bonded", "fixed"] == 2 * n_bottom
    assert n_free["bonded", "compliant"] - n_free["bonded", "sliding"] == (0 if sliding_pins(m) is None else 3)
    fixed, _ = constrained_components(m, "frictionless", "fixed", side="confined")
    assert fixed[m.nodes("side"), :2].all()
    for kwargs, what in ((dict(punch="glued"), "punch contact"), (dict(support="free"), "support"),
                         (dict(side="open"), "side")):
        with pytest.raises(ValueError, match=what):
            Biphasic(space, dict(E, kappa=1e-8), **kwargs)
    with pytest.raises(ValueError, match="support must be one of"):
        Indentation(space, get_law("elastic").resolve(E), support="free")
