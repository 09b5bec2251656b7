//! Which scene each sample of the stream takes: the pooled order (all shards, epoch by epoch)
//! or the mixed order (each sample's directory drawn from [`DataConfig::mix`]).

use rand::Rng;
use rand::seq::SliceRandom;

use super::seed::{mix, rng_for};
use super::sources::Sources;
use crate::train::TrainError;
use crate::train::config::DataConfig;

/// Where the stream's global sample `g` comes from: `(global shard, scene within the shard)`,
/// for [`DataConfig::mix`] unset (pooled) or set (mixed).
pub struct SampleOrder {
    kind: OrderKind,
}

enum OrderKind {
    Pooled(Order),
    Mixed(MixedOrder),
}

impl SampleOrder {
    /// The order of `sources` for `shares` ([`DataConfig::mix`]: one per directory, or empty
    /// for the pooled stream) and the run's `seed`. Shares that do not match the directories
    /// are an error ([`DataConfig::check_mix`]).
    pub fn new(sources: &Sources, shares: &[f32], seed: u64) -> Result<SampleOrder, TrainError> {
        let sizes = sources.shard_sizes();
        if shares.is_empty() {
            return Ok(SampleOrder {
                kind: OrderKind::Pooled(Order::new(sizes, seed)),
            });
        }
        DataConfig::check_mix(shares, sources.readers().len())?;
        let total: f64 = shares.iter().map(|&w| w as f64).sum();
        let mut acc = 0.0;
        let cdf = shares
            .iter()
            .map(|&w| {
                acc += w as f64 / total;
                acc
            })
            .collect();
        let mut first = 0;
        let directories = (0..sources.readers().len())
            .map(|d| {
                let n = sources.readers()[d].manifest().shards.len();
                let own = Order::new(
                    sizes[first..first + n].to_vec(),
                    mix(seed ^ mix(1000 + d as u64)),
                );
                let entry = (own, first);
                first += n;
                entry
            })
            .collect();
        Ok(SampleOrder {
            kind: OrderKind::Mixed(MixedOrder {
                last: shares.iter().rposition(|&w| w > 0.0).unwrap_or(0),
                cdf,
                directories,
                drawn: vec![0; shares.len()],
                next: 0,
                seed,
            }),
        })
    }

    /// `(global shard, scene within the shard)` of sample `g`. Mixed orders count the samples
    /// each directory has given, so they are cheapest called with increasing `g`; any `g`
    /// gives the same answer.
    pub fn locate(&mut self, g: u64) -> (usize, usize) {
        match &mut self.kind {
            OrderKind::Pooled(o) => o.locate(g),
            OrderKind::Mixed(m) => m.locate(g),
        }
    }
}

/// The pooled order: epoch `e` visits all shards in a seeded order and each shard's scenes in
/// a seeded order.
struct Order {
    /// Scene count per shard.
    shard_sizes: Vec<usize>,
    total: usize,
    seed: u64,
    /// Cached epoch layout: `(epoch, shard order, cumulative starts)`.
    cached: Option<(u64, Vec<usize>, Vec<usize>)>,
    /// Cached scene order of the shard in use: `(epoch, shard, scene order)`.
    scenes: Option<(u64, usize, Vec<usize>)>,
}

impl Order {
    fn new(shard_sizes: Vec<usize>, seed: u64) -> Order {
        Order {
            total: shard_sizes.iter().sum(),
            shard_sizes,
            seed,
            cached: None,
            scenes: None,
        }
    }

    fn locate(&mut self, g: u64) -> (usize, usize) {
        let epoch = g / self.total as u64;
        let pos = (g % self.total as u64) as usize;
        if self.cached.as_ref().is_none_or(|c| c.0 != epoch) {
            let mut perm: Vec<usize> = (0..self.shard_sizes.len()).collect();
            perm.shuffle(&mut rng_for(self.seed, 1, epoch));
            let mut starts = Vec::with_capacity(perm.len() + 1);
            let mut acc = 0;
            for &s in &perm {
                starts.push(acc);
                acc += self.shard_sizes[s];
            }
            starts.push(acc);
            self.cached = Some((epoch, perm, starts));
        }
        let (_, perm, starts) = self.cached.as_ref().expect("layout cached above");
        let i = starts.partition_point(|&s| s <= pos) - 1;
        let shard = perm[i];
        let start = starts[i];
        if self
            .scenes
            .as_ref()
            .is_none_or(|c| (c.0, c.1) != (epoch, shard))
        {
            let mut order: Vec<usize> = (0..self.shard_sizes[shard]).collect();
            order.shuffle(&mut rng_for(self.seed, 2, epoch * 1_000_003 + shard as u64));
            self.scenes = Some((epoch, shard, order));
        }
        let (_, _, order) = self.scenes.as_ref().expect("scene order cached above");
        (shard, order[pos - start])
    }
}

/// The mixed order: sample `g` draws its directory from the shares, then takes that
/// directory's next scene in the directory's own pooled order.
struct MixedOrder {
    /// Cumulative normalised shares, one per directory.
    cdf: Vec<f64>,
    /// The last directory with a positive share (where rounding at the top of `cdf` goes).
    last: usize,
    /// Each directory's own order and its first global shard.
    directories: Vec<(Order, usize)>,
    /// Samples each directory has given before sample `next`.
    drawn: Vec<u64>,
    next: u64,
    seed: u64,
}

impl MixedOrder {
    fn directory_of(&self, g: u64) -> usize {
        let u: f64 = rng_for(self.seed, 4, g).random();
        self.cdf.partition_point(|&c| c <= u).min(self.last)
    }

    fn locate(&mut self, g: u64) -> (usize, usize) {
        if g < self.next {
            self.drawn.iter_mut().for_each(|n| *n = 0);
            self.next = 0;
        }
        while self.next < g {
            let d = self.directory_of(self.next);
            self.drawn[d] += 1;
            self.next += 1;
        }
        let d = self.directory_of(g);
        let k = self.drawn[d];
        self.drawn[d] += 1;
        self.next = g + 1;
        let (order, first) = &mut self.directories[d];
        let (shard, scene) = order.locate(k);
        (*first + shard, scene)
    }
}
