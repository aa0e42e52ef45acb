"""The packed form of edge-mode sample records (raytrax.edges.records): one int32 array
that unpacks to the same records, field by field."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from raytrax.edges import Records
from raytrax.edges.records import pack_records, packed_rows, unpack_records


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
