"""Eight float64 lanes in an AVX-512 register, for the model's LLVM vector code (``linear``, ``block_ir``).

numba has no vector type, so the batch kernels build LLVM IR inside
``numba.extending.intrinsic``.  ``Lanes`` lets a formula written once for one
set (a plain-float numba function, through its ``py_func``) emit the same
operations for eight: ``+`` and ``*`` become ``fadd`` and ``fmul`` in the
formula's own order, with no fused multiply-adds, so each lane gets the
scalar function's bits.
"""

from __future__ import annotations

from llvmlite import ir

VEC = 8
V8 = ir.VectorType(ir.DoubleType(), VEC)


def const(x: float) -> ir.Constant:
    """An eight-lane vector of the constant x."""
    return ir.Constant(V8, [x] * VEC)


def splat(builder: ir.IRBuilder, x: ir.Value) -> ir.Value:
    """An eight-lane vector of the scalar value x."""
    v = builder.insert_element(ir.Constant(V8, ir.Undefined), x, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(v, ir.Constant(V8, ir.Undefined),
                                  ir.Constant(ir.VectorType(ir.IntType(32), VEC), [0] * VEC))


class Lanes:
    """An eight-lane float64 value under construction: arithmetic emits the vector instruction."""

    __slots__ = ("b", "v")

    def __init__(self, builder: ir.IRBuilder, value) -> None:
        self.b = builder
        self.v = const(value) if isinstance(value, float) else value

    def _other(self, x) -> ir.Value:
        return x.v if isinstance(x, Lanes) else const(float(x))

    def __add__(self, x):
        return Lanes(self.b, self.b.fadd(self.v, self._other(x)))

    def __radd__(self, x):
        return Lanes(self.b, self.b.fadd(self._other(x), self.v))

    def __mul__(self, x):
        return Lanes(self.b, self.b.fmul(self.v, self._other(x)))

    def __rmul__(self, x):
        return Lanes(self.b, self.b.fmul(self._other(x), self.v))
