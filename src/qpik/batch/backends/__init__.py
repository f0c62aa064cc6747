"""Batched back-ends: the interfaces (:mod:`.base`) and the CPU one (:mod:`.cpu`)."""
