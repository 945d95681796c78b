#!/usr/bin/env python3
"""SSIM of two fixed test images, computed as the two evaluations' own Python code does it,
written out from their definitions with nothing of svgir's: 3DGS's `utils/loss_utils.py::ssim`
(an 11x11 Gaussian window, sigma 1.5, applied as a 2-D cross-correlation with zero padding 5,
mean of the same-size map) and TensoIR's `rgb_ssim` (mip-NeRF's: the 1-D filter applied twice in
'valid' mode, variances clipped at 0 and |covariance| at sqrt(var0 var1)). Pure Python, so it runs
wherever Python 3 does. svgir-metrics' tests/ssim_reference.rs runs it and compares.

The images: W x H x 3 values k/255 from a 31-bit LCG (the test builds the same ones), and a second
image that is the first plus LCG noise, clamped to [0, 1].
Prints: `gs <value>` and `tensoir <value>` with 17 significant digits.
"""
import math
import sys

W, H, C = 23, 17, 3


def lcg(seed):
    s = seed
    while True:
        s = (s * 1103515245 + 12345) % (1 << 31)
        yield (s >> 16) % 256


def images():
    g = lcg(7)
    a = [next(g) / 255.0 for _ in range(W * H * C)]
    n = lcg(11)
    b = [min(1.0, max(0.0, x + (next(n) - 128) / 256.0)) for x in a]
    return a, b


def px(img, x, y, c):
    return img[(y * W + x) * C + c]


def gauss(size=11, sigma=1.5):
    g = [math.exp(-((i - size // 2) ** 2) / (2 * sigma * sigma)) for i in range(size)]
    s = sum(g)
    return [v / s for v in g]


def ssim_gs(a, b):
    g = gauss()
    win = [[g[i] * g[j] for j in range(11)] for i in range(11)]
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    total = 0.0
    for c in range(C):
        for y in range(H):
            for x in range(W):
                m = [0.0] * 5
                for dy in range(-5, 6):
                    for dx in range(-5, 6):
                        xx, yy = x + dx, y + dy
                        if 0 <= xx < W and 0 <= yy < H:
                            w = win[dy + 5][dx + 5]
                            p, q = px(a, xx, yy, c), px(b, xx, yy, c)
                            m[0] += w * p
                            m[1] += w * q
                            m[2] += w * p * p
                            m[3] += w * q * q
                            m[4] += w * p * q
                mu1, mu2 = m[0], m[1]
                s11, s22, s12 = m[2] - mu1 * mu1, m[3] - mu2 * mu2, m[4] - mu1 * mu2
                total += ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 * mu1 + mu2 * mu2 + c1) * (s11 + s22 + c2))
    return total / (W * H * C)


def ssim_tensoir(a, b):
    f = gauss()
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ow, oh = W - 10, H - 10

    def filt(z):  # z(x, y) -> 'valid' separable filter, first along y then along x
        col = [[sum(f[k] * z(x, y + k) for k in range(11)) for x in range(W)] for y in range(oh)]
        return [[sum(f[k] * col[y][x + k] for k in range(11)) for x in range(ow)] for y in range(oh)]

    total = 0.0
    for c in range(C):
        A = lambda x, y: px(a, x, y, c)
        B = lambda x, y: px(b, x, y, c)
        mu0, mu1 = filt(A), filt(B)
        e00 = filt(lambda x, y: A(x, y) ** 2)
        e11 = filt(lambda x, y: B(x, y) ** 2)
        e01 = filt(lambda x, y: A(x, y) * B(x, y))
        for y in range(oh):
            for x in range(ow):
                m0, m1 = mu0[y][x], mu1[y][x]
                s00 = max(0.0, e00[y][x] - m0 * m0)
                s11 = max(0.0, e11[y][x] - m1 * m1)
                s01 = e01[y][x] - m0 * m1
                s01 = math.copysign(min(math.sqrt(s00 * s11), abs(s01)), s01) if s01 != 0 else 0.0
                num = (2 * m0 * m1 + c1) * (2 * s01 + c2)
                den = (m0 * m0 + m1 * m1 + c1) * (s00 + s11 + c2)
                total += num / den
    return total / (ow * oh * C)


if __name__ == "__main__":
    a, b = images()
    print(f"gs {ssim_gs(a, b):.17g}")
    print(f"tensoir {ssim_tensoir(a, b):.17g}")
    sys.exit(0)
