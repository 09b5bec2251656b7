//! Learned physics world models in candle for Dynaserve: RigidFormer (anchors, ARoPE, differentiable Kabsch) with a batched multi-scene step API and checkpoint loading.
