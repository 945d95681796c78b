//! Wall time per phase of one rasterizer call, for `svgir bench raster`'s breakdown: where a
//! forward or backward spends its time (preprocess, binning, the tile kernels, reductions).

use std::time::Instant;

/// Named phase durations of one call, in the order they ran.
#[derive(Clone, Debug, Default)]
pub struct PhaseTimes {
    /// `(phase, milliseconds)`.
    pub ms: Vec<(&'static str, f64)>,
}

/// Laps of a running call: each [`Stopwatch::lap`] closes the phase that ran since the last.
pub(crate) struct Stopwatch {
    last: Instant,
    times: PhaseTimes,
}

impl Stopwatch {
    pub(crate) fn start() -> Self {
        Self { last: Instant::now(), times: PhaseTimes::default() }
    }

    pub(crate) fn lap(&mut self, phase: &'static str) {
        let now = Instant::now();
        self.times.ms.push((phase, (now - self.last).as_secs_f64() * 1e3));
        self.last = now;
    }

    pub(crate) fn finish(self) -> PhaseTimes {
        self.times
    }
}
