"""The packed and the compact forms of edge-mode sample records (raytrax.edges.records):
one int32 array that unpacks to the same records, field by field; small dtypes that widen
back to them."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from raytrax.edges import Records
from raytrax.edges.records import compact_records, pack_records, packed_rows, unpack_records, widen


@pytest.mark.parametrize("depth, lights", [(1, 0), (1, 2), (3, 1)])
def test_pack_then_unpack_gives_the_same_records(depth, lights):
    M = 7
    k = jax.random.split(jax.random.key(0), 5)
    r = Records(
        jax.random.randint(k[0], (depth, M), -2, 50, jnp.int32),
        jax.random.bernoulli(k[1], 0.5, (depth, M)),
        jax.random.randint(k[2], (depth, lights, M), -1, 50, jnp.int32),
        jax.random.randint(k[3], (depth, lights, M), -1, 50, jnp.int32),
        jax.random.randint(k[4], (depth, M), 0, 2, jnp.int32),
    )
    packed = pack_records(r)
    assert packed.shape == (packed_rows(depth, lights), M) == (depth * (3 + 2 * lights), M)
    assert packed.dtype == jnp.int32
    back = unpack_records(packed, depth, lights)
    for name, a, b in zip(Records._fields, r, back, strict=True):
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
    # Two records differ in the packed form exactly where they differ in some field.
    r2 = r._replace(last=r.last.at[..., 3].add(1)) if lights else r._replace(cell=r.cell.at[0, 3].add(1))
    same = np.asarray(jnp.all(pack_records(r2) == packed, 0))
    assert same.tolist() == [i != 3 for i in range(M)]


def test_unpack_refuses_an_array_of_the_wrong_size():
    with pytest.raises(ValueError, match="expected 5 for depth 1, 1 lights"):
        unpack_records(jnp.zeros((6, 2), jnp.int32), 1, 1)


@pytest.mark.parametrize("ids", [100, 40000])
def test_compact_records_widen_back_to_the_records(ids):
    """Compact records (int16 ids where the scene's ids fit, else int32; the pattern cell
    int8) widen back to the int32 records, sentinels (-1, -2) included."""
    rng = np.random.default_rng(0)
    D, L, M = 3, 2, 50
    r = Records(
        jnp.asarray(rng.integers(-2, ids, (D, M)), jnp.int32),
        jnp.asarray(rng.integers(0, 2, (D, M)) == 1),
        jnp.asarray(rng.integers(-1, ids, (D, L, M)), jnp.int32),
        jnp.asarray(rng.integers(-1, ids, (D, L, M)), jnp.int32),
        jnp.asarray(rng.integers(0, 2, (D, M)), jnp.int32),
    )
    c = compact_records(r, ids)
    assert c.hit.dtype == (jnp.int16 if ids < 32767 else jnp.int32) and c.cell.dtype == jnp.int8
    for name, a, b in zip(Records._fields, r, c, strict=True):
        assert widen(b).dtype == a.dtype, name
        np.testing.assert_array_equal(np.asarray(widen(b)), np.asarray(a), err_msg=name)
