"""Two-sample statistics for the grader, standard library only.

welch(a, b): Welch's t-test of equal means from two independent samples whose
variances may differ (both variances counted), two-sided p-value from the t
distribution with Welch-Satterthwaite degrees of freedom.
variance_ratio(a, b): one-sided F test that a's variance is not larger than b's.
holm(pvalues): Holm's step-down adjusted p-values (family-wise error control).
t_quantile(alpha, df), f_quantile(alpha, d1, d2): the bounds that two-sided t and
one-sided F tests at level alpha use (tests/lib.py takes its tolerances from them).
"""
import math


def _betacf(a, b, x):
    """Continued fraction of the incomplete beta function (Numerical Recipes, modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 400):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def betainc(a, b, x):
    """Regularized incomplete beta I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def t_two_sided(t, df):
    """P(|T| >= |t|) for Student's t with df degrees of freedom."""
    if math.isnan(t):
        return 0.0
    if math.isinf(t):
        return 0.0
    return betainc(df / 2.0, 0.5, df / (df + t * t))


def f_upper(f, d1, d2):
    """P(F >= f) for the F distribution with (d1, d2) degrees of freedom."""
    if f <= 0.0:
        return 1.0
    return betainc(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f))


def _invert(upper_tail, alpha):
    """The x >= 0 with upper_tail(x) = alpha, for a decreasing upper_tail (bisection)."""
    lo, hi = 0.0, 1.0
    while upper_tail(hi) > alpha:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if upper_tail(mid) > alpha:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return 0.5 * (lo + hi)


def t_quantile(alpha, df):
    """The t with P(|T| >= t) = alpha for Student's t with df degrees of freedom."""
    return _invert(lambda t: t_two_sided(t, df), alpha)


def f_quantile(alpha, d1, d2):
    """The f with P(F >= f) = alpha for the F distribution with (d1, d2) degrees of freedom."""
    return _invert(lambda f: f_upper(f, d1, d2), alpha)


def mean_var(xs):
    n = len(xs)
    m = sum(xs) / n
    return m, sum((x - m) ** 2 for x in xs) / (n - 1)


def welch(a, b, floor=0.0):
    """(t, df, p, difference, standard error) for mean(a) - mean(b).  `floor` is added to the
    variance of the difference (for values that are exact up to rounding, where both samples may
    have no variance at all)."""
    ma, va = mean_var(a)
    mb, vb = mean_var(b)
    sa, sb = va / len(a), vb / len(b)
    se2 = sa + sb + floor
    d = ma - mb
    if se2 <= 0.0:
        return (0.0 if d == 0.0 else math.inf), math.inf, (1.0 if d == 0.0 else 0.0), d, 0.0
    denominator = (sa * sa / (len(a) - 1) if sa else 0.0) + (sb * sb / (len(b) - 1) if sb else 0.0)
    df = se2 * se2 / denominator if denominator > 0.0 else 1e9
    df = max(1.0, min(df, 1e9))
    t = d / math.sqrt(se2)
    return t, df, t_two_sided(t, df), d, math.sqrt(se2)


def variance_ratio(a, b):
    """(ratio, p) of the one-sided F test H0: Var(a) <= Var(b) against Var(a) > Var(b)."""
    _, va = mean_var(a)
    _, vb = mean_var(b)
    if vb <= 0.0:
        return (math.inf if va > 0.0 else 1.0), (0.0 if va > 0.0 else 1.0)
    ratio = va / vb
    return ratio, f_upper(ratio, len(a) - 1, len(b) - 1)


def holm(pvalues):
    """Holm-adjusted p-values, in the input order."""
    m = len(pvalues)
    order = sorted(range(m), key=lambda i: pvalues[i])
    adjusted = [0.0] * m
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * pvalues[i]))
        adjusted[i] = running
    return adjusted
