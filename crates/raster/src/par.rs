//! Work distribution: tiles are dealt round-robin to one task per thread, each owning
//! an accumulation buffer, so per-Gaussian sums need no atomics; the fixed assignment
//! and the fixed order of the final sum make results independent of scheduling (the
//! same inputs give bit-identical gradients on a given thread count).

/// Runs `work(item, &mut buffer)` for every `item < count`, with one buffer per
/// worker thread created by `make`; returns the buffers.
pub fn for_each_with_buffers<B: Send>(
    count: usize,
    make: impl Fn() -> B + Sync,
    work: impl Fn(usize, &mut B) + Sync,
) -> Vec<B> {
    let workers = rayon::current_num_threads().clamp(1, count.max(1));
    let mut buffers: Vec<Option<B>> = (0..workers).map(|_| None).collect();
    rayon::scope(|s| {
        for (w, slot) in buffers.iter_mut().enumerate() {
            let (make, work) = (&make, &work);
            s.spawn(move |_| {
                let mut buf = make();
                for i in (w..count).step_by(workers) {
                    work(i, &mut buf);
                }
                *slot = Some(buf);
            });
        }
    });
    buffers.into_iter().flatten().collect()
}

/// Sums equally long buffers element-wise into the first one, in parallel.
pub fn sum_into_first(mut bufs: Vec<Vec<f32>>) -> Vec<f32> {
    use rayon::prelude::*;
    let Some(mut first) = (!bufs.is_empty()).then(|| bufs.swap_remove(0)) else {
        return Vec::new();
    };
    first.par_chunks_mut(1 << 14).enumerate().for_each(|(c, chunk)| {
        let off = c << 14;
        let len = chunk.len();
        for b in &bufs {
            for (d, s) in chunk.iter_mut().zip(&b[off..off + len]) {
                *d += s;
            }
        }
    });
    first
}

/// A raw pointer that may be shared between threads writing disjoint ranges.
#[derive(Clone, Copy)]
pub struct SharedMut<T>(pub *mut T);
unsafe impl<T> Send for SharedMut<T> {}
unsafe impl<T> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    /// The pointer (a method, so closures capture the whole `Send` wrapper).
    pub fn get(self) -> *mut T {
        self.0
    }
}
