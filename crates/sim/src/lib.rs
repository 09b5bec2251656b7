//! Ground-truth rigid and soft-body trajectories from rapier3d for Dynaserve: MOVi-like and WreckingBall scene generators and the safetensors dataset format.
