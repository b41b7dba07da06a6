"""Reference values for the NB2 known-answer tests, in 50-digit arithmetic (mpmath).

Near the dispersion boundary (alpha around 1e-5) double-precision NB2 code loses digits:
lnGamma(y + 1/alpha) - lnGamma(1/alpha) cancels to about 1e-8 of the likelihood, and the
digamma and trigamma differences of the score and Hessian lose as much. This script finds the
maximum of the NB2 likelihood by Newton's method on (beta0, beta1, alpha) with 50 digits and
computes statsmodels' trial-clustered sandwich there (H^-1 (sum_g s_g s_g^T) H^-1 times
G/(G-1) (N-1)/(N-K), K = 3), with normal Wald intervals and p values.

    python3 nb2_reference.py COUNTS BETA0 BETA1 ALPHA

COUNTS: comma-separated counts of 6 trials x 15 minutes (design: intercept, minute); the
starting values need only be near the maximum (statsmodels' fit gives them).
"""
import sys

import mpmath as mp

mp.mp.dps = 50
y = [int(v) for v in sys.argv[1].split(",")]
n = len(y)
X = [(1, i % 15) for i in range(n)]
trial = [i // 15 for i in range(n)]


def terms(b0, b1, a):
    r = 1 / a
    g = [mp.mpf(0)] * 3
    H = [[mp.mpf(0)] * 3 for _ in range(3)]
    ll = mp.mpf(0)
    scores = []
    for (x0, x1), yi in zip(X, y):
        mu = mp.e ** (b0 * x0 + b1 * x1)
        ll += (mp.loggamma(yi + r) - mp.loggamma(r) - mp.loggamma(yi + 1)
               + r * mp.log(r / (r + mu)) + yi * mp.log(mu / (r + mu)))
        am = 1 + a * mu
        gb = (yi - mu) / am
        gr = mp.digamma(yi + r) - mp.digamma(r) + mp.log(r / (r + mu)) + (mu - yi) / (r + mu)
        s = [gb * x0, gb * x1, -r * r * gr]
        scores.append(s)
        hbb = -mu * (1 + a * yi) / am**2
        hba = -(yi - mu) * mu / am**2
        gpr = (mp.polygamma(1, yi + r) - mp.polygamma(1, r) + 1 / r - 1 / (r + mu)
               - (mu - yi) / (r + mu) ** 2)
        xs = [x0, x1]
        for i in range(2):
            for j in range(2):
                H[i][j] += hbb * xs[i] * xs[j]
            H[i][2] += hba * xs[i]
            H[2][i] += hba * xs[i]
        H[2][2] += 2 * r**3 * gr + r**4 * gpr
        for i in range(3):
            g[i] += s[i]
    return ll, g, H, scores


theta = [mp.mpf(v) for v in sys.argv[2:5]]
for _ in range(50):
    ll, g, H, S = terms(*theta)
    step = mp.lu_solve(mp.matrix(H), mp.matrix(g))
    theta = [theta[i] - step[i] for i in range(3)]
    if max(abs(v) for v in step) < mp.mpf(10) ** -40:
        break
ll, g, H, S = terms(*theta)
h_inv = mp.inverse(mp.matrix(H))
groups = max(trial) + 1
meat = mp.matrix(3, 3)
for c in range(groups):
    s = [sum(S[i][k] for i in range(n) if trial[i] == c) for k in range(3)]
    for i in range(3):
        for j in range(3):
            meat[i, j] += s[i] * s[j]
cov = h_inv * meat * h_inv * (mp.mpf(groups) / (groups - 1) * mp.mpf(n - 1) / (n - 3))
se = [mp.sqrt(cov[i, i]) for i in range(3)]
z95 = mp.sqrt(2) * mp.erfinv(mp.mpf("0.95"))
print("params", [mp.nstr(v, 17) for v in theta])
print("llf", mp.nstr(ll, 17), "gradient", [mp.nstr(v, 3) for v in g])
print("se", [mp.nstr(v, 17) for v in se])
for j in range(2):
    p = mp.erfc(abs(theta[j] / se[j]) / mp.sqrt(2))
    print("p", j, mp.nstr(p, 17), "ci", mp.nstr(theta[j] - z95 * se[j], 17),
          mp.nstr(theta[j] + z95 * se[j], 17))
