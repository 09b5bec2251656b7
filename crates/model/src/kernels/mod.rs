//! CPU kernels as candle custom ops: each fuses a composition of candle ops into one pass and
//! is tested against that composition (forward, and the gradient where training uses it).
//! Other devices keep the plain composition.

pub mod activation;
pub mod activation_grad;
pub mod attention;
pub mod attention_grad;
mod attention_keys;
mod attention_long;
mod attention_ops;
pub mod avp;
pub mod grouped_mlp;
pub mod kabsch;
pub mod linear;
pub mod norm;
pub mod pool;
pub(crate) mod product;
pub mod simd;
mod storage;
#[cfg(test)]
mod test_data;
