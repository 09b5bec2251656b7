//! Streaming training data: a worker thread reads dataset shards, draws one-step windows with
//! augmentation, prepares the scenes for the model and hands whole batches to the trainer
//! through a bounded channel.
//!
//! The sample stream is a pure function of `(run seed, global sample index)`: epoch `e` visits
//! the shards in a seeded random order and the scenes of each shard in a seeded random order,
//! and sample `g` draws its window and augmentation from a generator seeded with `(seed, g)`.
//! With [`DataConfig::mix`](super::config::DataConfig::mix) set, sample `g` first draws its directory from the shares (a
//! generator seeded with `(seed, g)`) and then takes that directory's next scene in the
//! directory's own epoch order, so batches mix the directories.
//! Resuming at iteration `s` therefore restarts the stream at sample `s * batch_size` and
//! reproduces exactly the batches an uninterrupted run would have seen.
//!
//! Each part has its own file: `seed` (the stream's generators), `window` (one augmented
//! window of a scene), `sources` (the directories as one sequence of shards), `sample_order`
//! (which scene each sample takes), `loader` (the worker thread and its batches) and
//! `normalization` (the feature normalisation fitted from the data).

mod loader;
mod normalization;
mod sample_order;
mod seed;
mod sources;
mod window;

pub use loader::{Batch, Loader, Sample};
pub use normalization::fit_normalization;
pub use sample_order::SampleOrder;
pub use seed::mix;
pub use sources::Sources;
pub use window::{Window, mirror_point, mirror_rotation, sample_window};
