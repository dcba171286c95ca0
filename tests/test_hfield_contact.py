"""env.hfield_foot_contacts (quadson_mjx.hfield_contact): one contact per foot on a height field.

The reference for the contact is MuJoCo C's height-field collision (mj_forward): of a free sphere
of the foot's radius on the stone field's and the tiled ground's height fields at random places
touching the ground, and of the robot's feet at poses over the stones; the single contact MJX makes
is C's deepest contact there, distance, normal and position. The rows are counted by hand, the
swap's scope is checked on MJX's own table, and the environment that trains with it is stepped
jitted and vmapped."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from mujoco.mjx._src import collision_driver, mesh
from mujoco.mjx._src.collision_types import GeomInfo
from mujoco.mjx._src.types import GeomType

from quadson_mjx import hfield_contact, terrain
from quadson_mjx.config import apply_overrides
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import check_env_config, env_config
from quadson_mjx.env_model import training_model
from quadson_mjx.robots import get_robot

PAIR = (GeomType.HFIELD, GeomType.SPHERE)
STONES = ["terrain=rough", "base_terrain_contact=false", "joint_limits=false"]


@pytest.fixture(scope="module")
def one_contact_env():
    return LocomotionEnv(apply_overrides(env_config(), [*STONES, "hfield_foot_contacts=1"]))


def _foot_rows(env) -> tuple[int, int]:
    """(contacts of the foot spheres, constraint rows) of a fresh data made under env's setting."""
    with hfield_contact.sphere_contacts(env.config.hfield_foot_contacts):
        d = mjx.make_data(env.sys)
    return int(d._impl.contact.dist.shape[0]), int(d._impl.efc_J.shape[0])


def test_rows_by_hand(one_contact_env):
    # 4 five-bar closures x 3 connect rows = 12; a condim-3 pyramidal contact has 4 rows; the feet
    # are the only geoms that meet the ground (base_terrain_contact=false): 4 contacts each under
    # MJX's own collider, 1 with the option, as on a plane
    four = LocomotionEnv(apply_overrides(env_config(), STONES))
    assert _foot_rows(four) == (16, 12 + 16 * 4)
    assert _foot_rows(one_contact_env) == (4, 12 + 4 * 4)


def test_the_swap_is_scoped_and_checked():
    own = collision_driver._COLLISION_FUNC[PAIR]
    with hfield_contact.sphere_contacts(1):
        assert collision_driver._COLLISION_FUNC[PAIR] is hfield_contact.surface_sphere_contact
        with hfield_contact.sphere_contacts(4):
            assert collision_driver._COLLISION_FUNC[PAIR] is own
        assert collision_driver._COLLISION_FUNC[PAIR] is hfield_contact.surface_sphere_contact
    assert collision_driver._COLLISION_FUNC[PAIR] is own
    with pytest.raises(ValueError, match="hfield_foot_contacts must be one of"):
        with hfield_contact.sphere_contacts(2):
            pass
    assert collision_driver._COLLISION_FUNC[PAIR] is own


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        (["hfield_foot_contacts=2"], "env.hfield_foot_contacts is 2"),
        (["hfield_foot_contacts=1", "impl=warp"], "needs env.impl=jax"),
    ],
)
def test_bad_values_name_the_key(overrides, match):
    cfg = apply_overrides(env_config(), [*STONES, *overrides])
    with pytest.raises(ValueError, match=match):
        check_env_config(cfg)


def test_getup_task_refuses_it():
    cfg = env_config(task="getup", terrain="rough")
    cfg.hfield_foot_contacts = 1
    with pytest.raises(ValueError, match="the locomotion task"):
        check_env_config(cfg)


FOOT_RADIUS_M = 0.015  # the foot spheres' (models/quadson)


def _sphere_on(m: mujoco.MjModel) -> mujoco.MjModel:
    """A free sphere of the foot's radius on m's floor height field (its size, place and samples)."""
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, terrain.FLOOR_GEOM)
    h = m.geom_dataid[g]
    nrow, ncol, size, pos = m.hfield_nrow[h], m.hfield_ncol[h], m.hfield_size[h], m.geom_pos[g]
    sphere = mujoco.MjModel.from_xml_string(f"""<mujoco><asset>
        <hfield name="ground" nrow="{nrow}" ncol="{ncol}" size="{" ".join(map(str, size))}"/></asset>
        <worldbody><geom type="hfield" hfield="ground" pos="{" ".join(map(str, pos))}"/>
        <body><freejoint/><geom type="sphere" size="{FOOT_RADIUS_M}"/></body></worldbody></mujoco>""")
    adr = m.hfield_adr[h]
    sphere.hfield_data[:] = m.hfield_data[adr : adr + nrow * ncol]
    return sphere


@pytest.mark.parametrize("ground", ["rough", "tiles"])
def test_the_surface_contact_is_mujoco_cs_deepest(ground):
    """Spheres at random places of the ground, their centres 0-15 mm above it (MuJoCo C's ray
    cast finds the ground): our contact against C's deepest of the sphere, on the stones (4 cm
    cells, the subgrid 2 x 2) and the tiles (2 cm cells, 3 x 3; slopes to 20 degrees, steps and
    stairs, where MJX's own prism test goes wrong, module docstring)."""
    m = training_model(get_robot("quadson"), env_config(terrain=ground))
    sphere = _sphere_on(m)
    size, pos = sphere.hfield_size[0], sphere.geom_pos[0]
    tick = 2 * size[0] / (sphere.hfield_ncol[0] - 1)
    sub = int(np.ceil(2 * FOOT_RADIUS_M / tick)) + 1  # as MJX sizes the subgrid of a geom's bound
    assert sub == {"rough": 2, "tiles": 3}[ground]
    d = mujoco.MjData(sphere)
    d.qpos[:3] = [*pos[:2], pos[2] + size[2] + 2.0]  # out of the way of the rays
    mujoco.mj_forward(sphere, d)
    rng = np.random.default_rng(0)
    centres = []
    while len(centres) < 300:
        xy = pos[:2] + rng.uniform(-0.95, 0.95, 2) * size[:2]
        top = np.array([*xy, pos[2] + size[2] + 1.0])
        geomid = np.zeros(1, np.int32)
        depth = mujoco.mj_ray(sphere, d, top, np.array([0.0, 0.0, -1.0]), None, 1, 1, geomid)
        assert depth > 0 and geomid[0] == 0
        centres.append([*xy, top[2] - depth + rng.uniform(0.0, FOOT_RADIUS_M)])
    centres = np.array(centres)
    h = mesh.hfield(sphere, 0).replace(pos=jnp.asarray(pos, jnp.float32), mat=jnp.eye(3))
    h = h.replace(data=jnp.asarray(h.data, jnp.float32))
    contact = jax.jit(jax.vmap(lambda c: hfield_contact.nearest_on_surface(
        h, GeomInfo(c, jnp.eye(3), jnp.array([FOOT_RADIUS_M, 0.0, 0.0])), (sub, sub))))  # fmt: skip
    dist, cpos, frame = (np.asarray(a) for a in contact(jnp.asarray(centres, jnp.float32)))
    compared = 0
    for w, c in enumerate(centres):
        d.qpos[:] = [*c, 1, 0, 0, 0]
        mujoco.mj_forward(sphere, d)
        assert d.ncon > 0  # the sphere reaches the ground
        deepest = min(d.contact[: d.ncon], key=lambda k: k.dist)
        assert dist[w] == pytest.approx(deepest.dist, abs=5e-6)
        # both normals from the ground to the sphere (C's geom1 is the height field)
        assert float(np.dot(frame[w, 0], deepest.frame[:3])) > 1 - 1e-4
        np.testing.assert_allclose(cpos[w], deepest.pos, atol=5e-5)
        compared += 1
    assert compared == len(centres)


def _poses_over_stones(env, n: int, seed: int = 0) -> np.ndarray:
    """n home poses over random points of the stone field away from its flat patch, each lowered
    so that its lowest foot sphere reaches 2 mm below the ground height under its centre (the
    env's height query; on a sloped cell the contact itself is for MuJoCo C to find)."""
    m = env.mj_model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    feet = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in env.robot.foot_geoms()]
    poses = []
    while len(poses) < n:
        q = np.array(env._home_qpos, np.float64)
        q[:2] = rng.uniform(0.6, 2.5, 2) * rng.choice([-1, 1], 2)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        low = min(
            d.geom_xpos[f, 2] - m.geom_size[f, 0] - float(env.ground_height(jnp.asarray(d.geom_xpos[f, :2])))
            for f in feet
        )
        q[2] -= low + 0.002
        poses.append(q)
    return np.stack(poses)


def test_the_contact_is_mujoco_cs_deepest(one_contact_env):
    env = one_contact_env
    m = env.mj_model
    feet = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in env.robot.foot_geoms()])
    poses = _poses_over_stones(env, 6)
    with hfield_contact.sphere_contacts(1):
        d0 = mjx.make_data(env.sys)
        forward = jax.jit(jax.vmap(lambda q: mjx.forward(env.sys, d0.replace(qpos=q))))
        dx = forward(jnp.asarray(poses, jnp.float32))
    c = dx._impl.contact
    d = mujoco.MjData(m)
    compared = 0
    for w, q in enumerate(poses):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        for f in feet:
            ours = [i for i in range(c.dist.shape[1]) if f in (int(c.geom1[w, i]), int(c.geom2[w, i]))]
            assert len(ours) == 1  # one contact per foot, always allocated
            theirs = [i for i in range(d.ncon) if f in (d.contact[i].geom1, d.contact[i].geom2)]
            if not theirs:  # no contact in C: ours is inactive (distance >= 0)
                assert float(c.dist[w, ours[0]]) >= -1e-5
                continue
            deepest = min(theirs, key=lambda i: d.contact[i].dist)
            np.testing.assert_allclose(float(c.dist[w, ours[0]]), d.contact[deepest].dist, atol=2e-5)
            # the normal: MJX's frame row 0 and C's contact frame row 0 (both from ground to foot
            # or both the other way: compare up to sign through the dot product's magnitude)
            dot = abs(float(np.dot(np.asarray(c.frame[w, ours[0], 0]), d.contact[deepest].frame[:3])))
            assert dot > 1 - 1e-3
            compared += 1
    assert compared >= 6  # the lowest foot of every pose at least


def test_env_steps_jitted_and_vmapped(one_contact_env):
    env = one_contact_env
    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(jax.vmap(env.step))
    for _ in range(3):
        state = step(state, jnp.zeros((2, env.action_size)))
    assert bool(jnp.all(jnp.isfinite(state.pipeline_state.qpos)))
    assert state.pipeline_state._impl.contact.dist.shape == (2, 4)
    # the feet's contact flags read the one contact (a trot: at least the stance pair down)
    assert int(jnp.sum(env.foot_contact(jax.tree.map(lambda x: x[0], state.pipeline_state)))) >= 2
    assert collision_driver._COLLISION_FUNC[PAIR] is not hfield_contact.surface_sphere_contact
