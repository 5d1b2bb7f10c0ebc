"""Generates the explicit real SH polynomials of bands 0..4 used by prt-sphere's fast path.

Uses the same normalised recurrence as the general path (sh.rs), symbolically, in the textbook
frame (x_t, y_t, z_t) with z_t the polar axis; prt maps x_t = z, y_t = x, z_t = y (+Y up).
Run: python3 crates/prt-sphere/scripts/gen_sh.py > /tmp/sh_explicit.rs
"""
import sympy as sp

x, y, z = sp.symbols("x y z")  # textbook frame
LMAX = 4
pi = sp.pi

p = {}
p[(0, 0)] = sp.sqrt(1 / (4 * pi))
for m in range(1, LMAX + 1):
    p[(m, m)] = -sp.sqrt(sp.Rational(2 * m + 1, 2 * m)) * p[(m - 1, m - 1)]
for m in range(0, LMAX + 1):
    if m + 1 <= LMAX:
        p[(m + 1, m)] = z * sp.sqrt(2 * m + 3) * p[(m, m)]
    for l in range(m + 2, LMAX + 1):
        a = sp.sqrt(sp.Rational(4 * l * l - 1, l * l - m * m))
        b = sp.sqrt(sp.Rational((l - 1) ** 2 - m * m, 4 * (l - 1) ** 2 - 1))
        p[(l, m)] = sp.expand(a * (z * p[(l - 1, m)] - b * p[(l - 2, m)]))

# prt frame names: textbook x_t = Z, y_t = X, z_t = Y
to_prt = {x: sp.Symbol("dz"), y: sp.Symbol("dx"), z: sp.Symbol("dy")}
lines = []
for l in range(LMAX + 1):
    for m in range(-l, l + 1):
        am = abs(m)
        c = sp.expand((x + sp.I * y) ** am)
        trig = sp.re(c) if m >= 0 else sp.im(c)
        trig = sp.expand(sp.re(sp.expand((x + sp.I * y) ** am)) if m >= 0 else sp.im(sp.expand((x + sp.I * y) ** am)), complex=False)
        # x, y are real: recompute without assumptions issues
        xr, yr = sp.symbols("xr yr", real=True)
        c = sp.expand((xr + sp.I * yr) ** am)
        trig = (sp.re(c) if m >= 0 else sp.im(c)).subs({xr: x, yr: y})
        scale = 1 if m == 0 else sp.sqrt(2)
        expr = sp.expand(scale * p[(l, am)] * trig)
        expr = expr.subs(to_prt, simultaneous=True)
        poly = sp.Poly(expr, sp.Symbol("dx"), sp.Symbol("dy"), sp.Symbol("dz"))
        terms = []
        for (ex, ey, ez), coef in poly.terms():
            mon = "*".join(["dx"] * ex + ["dy"] * ey + ["dz"] * ez) or "1.0"
            terms.append(f"({float(sp.N(coef, 30))!r}) * {mon}")
        idx = l * (l + 1) + m
        lines.append(f"    out[{idx}] = {' + '.join(terms)};")
print("\n".join(lines))
