"""Pure scattering maths (no plugin code): SGGX, SpongeCake layers, sheen.

Every function here takes and returns Dr.Jit arrays of the active Mitsuba
variant, so the same code runs in scalar, LLVM and CUDA variants.
"""
