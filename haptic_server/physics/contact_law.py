"""The contact law of every world (seed 001 eq 8): penalty along the normal and a stick
spring along the tangent capped at Coulomb's cone, and a contact's rows in the implicit
step."""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def penalty_friction(law, depth, vn, vt, stick, h):
    """Seed 001 eq 8 at one contact point, law = (k_n, b_n, mu, k_t): the normal force
    k_n delta - b_n v_n (>= 0) and the stick spring's tangential force -k_t s - b_n v_t
    capped at mu f_n, s the stick's deflection carried on by v_t h. depth delta >= 0 is the
    penetration, v_n < 0 approaches.
    Returns (f_n, f_t, the new deflection, whether it sticks). A capped contact's anchor
    slides only by what the spring itself carries past the cone (its deflection clipped at
    mu f_n / k_t), so it moves with v_t: a cap crossed by the damping's share b_n v_t moves
    no anchor (set to the capped force's -f_t / k_t, the deflection grew against v_t on
    every such tick, and sensor noise ratcheted a held box up its pads)."""
    k_n, b_n, mu, k_t = law
    f_n = k_n * depth - b_n * vn
    if f_n < 0.0:
        f_n = 0.0
    stick += vt * h
    f_t = -k_t * stick - b_n * vt
    limit = mu * f_n
    if abs(f_t) > limit:
        f_t = limit if f_t > 0.0 else -limit
        if k_t <= 0.0:
            return f_n, f_t, 0.0, False
        edge = limit / k_t
        return f_n, f_t, min(edge, max(-edge, stick)), False
    return f_n, f_t, stick, True


@njit(cache=True)
def add_rows(kmat, bmat, cols, jn, jt, count, gains):
    """A contact's stiffness and damping over its columns (cols[:count]; -1: a wall's):
    K += kn jn jn^T + kt jt jt^T, B += bn jn jn^T + bt jt jt^T, gains = (kn, kt, bn, bt)."""
    kn, kt, bn, bt = gains
    for i in range(count):
        a = cols[i]
        if a < 0:
            continue
        for j in range(count):
            b = cols[j]
            if b < 0:
                continue
            nn = jn[i] * jn[j]
            tt = jt[i] * jt[j]
            kmat[a, b] += kn * nn + kt * tt
            bmat[a, b] += bn * nn + bt * tt
