"""DEBT (Depth Embedded Block Tree): the progressive image codec of rovlink.

A wavelet transform (CDF 9/7, or integer 5/3 for lossless streams), an
embedded block-tree bit-plane coder (SPECK-style set partitioning) with a
region of interest raised SHIFT planes, and an adaptive binary arithmetic
coder.  Every prefix of a stream that holds its header is a picture, and a
longer prefix is a better one.

    data = debt.encode(image, budget, roi=(x0, y0, x1, y1), shift=6)
    picture = debt.decode(data[:n])
    debt.warm_up()   # compile the kernels ahead of the first image
    debt.warm_up_in_background()   # the same in a daemon thread (returned)

decode raises ValueError for bytes it cannot decode, and its subclass
IncompleteStream while the bytes do not yet hold the header (wait for more).
"""

from .codec import Header, decode, encode, unpack_header, warm_up, warm_up_in_background
from .header import IncompleteStream

__all__ = ["encode", "decode", "Header", "IncompleteStream", "unpack_header", "warm_up", "warm_up_in_background"]
