"""Batched back-ends: the interface (:mod:`.base`), the CPU one (:mod:`.cpu`), the Warp one
(:mod:`.warp`) and the device mirrors of the engine's primitives (:mod:`.warp_mirror`)."""
