"""Small 2-D vector helpers. Vectors are arrays with a last axis of size 2 (x, y)."""

import jax.numpy as jnp


def rotation(angle):
    """The rotation by ``angle`` (rad) as a unit vector (cos, sin)."""
    return jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)


def rotate(v, rot):
    """Rotate ``v`` by the rotation ``rot`` = (cos, sin): complex multiplication."""
    c, s = rot[..., 0], rot[..., 1]
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def relative_rotation(local, glob):
    """The rotation taking the vector ``local`` onto the direction of ``glob``,
    assuming |glob| == |local|: glob * conj(local) / |local|^2, no sqrt or atan2."""
    n2 = dot(local, local)
    return jnp.stack([dot(glob, local), cross(local, glob)], axis=-1) / n2[..., None]


def perp(v):
    """``v`` turned by +90 degrees: the left normal of a direction."""
    return jnp.stack([-v[..., 1], v[..., 0]], axis=-1)


def cross(a, b):
    """z component of the 3-D cross product of two planar vectors."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def heading(v):
    """Angle of ``v`` from +x, counterclockwise, in (-pi, pi]."""
    return jnp.arctan2(v[..., 1], v[..., 0])


def safe_norm(v, eps=1e-300):
    """Euclidean norm whose gradient is finite at zero."""
    sq = dot(v, v)
    is_zero = sq <= eps
    return jnp.where(is_zero, 0.0, jnp.sqrt(jnp.where(is_zero, 1.0, sq)))


def safe_sqrt(x, ok):
    """sqrt(x) where ``ok``; 0 elsewhere, with finite gradients everywhere."""
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


def unit(v):
    n = safe_norm(v)
    return v / jnp.where(n > 0, n, 1.0)[..., None]
