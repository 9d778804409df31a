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
    inv = 1.0 / dot(local, local)  # usually a constant of the link: the division is hoisted
    return jnp.stack([dot(glob, local) * inv, cross(local, glob) * inv], axis=-1)


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


def wrap_angle(delta):
    """An angle (difference, rad) wrapped to [-pi, pi)."""
    return jnp.remainder(delta + jnp.pi, 2.0 * jnp.pi) - jnp.pi


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


class V2:
    """A 2-D vector kept as two separate arrays (x, y): structure of arrays.

    The closed-form groups compute with V2 instead of (..., 2) arrays so that the
    traced program has no stack/slice pairs between steps; XLA then fuses a whole
    position analysis into one or two loops (see benchmarks/bench_kinematics.py).
    Arrays are built only where a :class:`Frame` or an output needs them.
    """

    __slots__ = ("x", "y")

    def __init__(self, x, y):
        self.x, self.y = x, y

    @staticmethod
    def of(a) -> "V2":
        """The components of an array whose last axis is (x, y)."""
        return V2(a[..., 0], a[..., 1])

    def array(self):
        return jnp.stack([self.x, self.y], axis=-1)

    def __add__(self, o):
        return V2(self.x + o.x, self.y + o.y)

    def __sub__(self, o):
        return V2(self.x - o.x, self.y - o.y)

    def __mul__(self, k):
        """Scaled by a scalar array ``k``. Write ``v * k``: with a JAX array on the
        left, JAX would try to read the V2 as an array."""
        return V2(self.x * k, self.y * k)

    def __neg__(self):
        return V2(-self.x, -self.y)

    def dot(self, o):
        return self.x * o.x + self.y * o.y

    def cross(self, o):
        """z component of self x o."""
        return self.x * o.y - self.y * o.x

    def perp(self) -> "V2":
        """Turned by +90 degrees (the left normal)."""
        return V2(-self.y, self.x)

    def rotate(self, rot: "V2") -> "V2":
        """Rotated by the unit vector ``rot`` = (cos, sin): complex multiplication."""
        return V2(rot.x * self.x - rot.y * self.y, rot.y * self.x + rot.x * self.y)

    def unit(self) -> "V2":
        """Unit vector (a zero vector stays zero)."""
        n2 = self.dot(self)
        inv = jnp.where(n2 > 0, 1.0 / jnp.sqrt(jnp.where(n2 > 0, n2, 1.0)), 0.0)
        return self * inv
