//! Best-of-N wall-clock timing for the benchmarks: the fastest run is the least
//! disturbed measurement on a shared machine.

use std::convert::Infallible;
use std::time::Instant;

/// Runs `f` `warmups` times untimed, then `reps` times (at least once) timed; returns
/// the fastest timed run in seconds and the last run's result.
pub fn best_of<T>(warmups: usize, reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    match try_best_of(warmups, reps, || Ok::<T, Infallible>(f())) {
        Ok(timed) => timed,
        Err(never) => match never {},
    }
}

/// [`best_of`] for a fallible `f`: the first error ends the timing and is returned.
pub fn try_best_of<T, E>(
    warmups: usize,
    reps: usize,
    mut f: impl FnMut() -> Result<T, E>,
) -> Result<(f64, T), E> {
    for _ in 0..warmups {
        f()?;
    }
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        let r = f()?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(r);
    }
    Ok((best, last.expect("at least one timed run")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_runs_and_stops_at_the_first_error() {
        let mut runs = 0;
        let (secs, last) = best_of(2, 3, || {
            runs += 1;
            runs
        });
        assert_eq!((runs, last), (5, 5));
        assert!(secs >= 0.0 && secs.is_finite());
        assert_eq!(best_of(0, 0, || 7).1, 7, "at least one run");
        let mut runs = 0;
        let r: Result<(f64, ()), &str> = try_best_of(0, 5, || {
            runs += 1;
            if runs == 2 {
                Err("second")
            } else {
                Ok(())
            }
        });
        assert_eq!((r.unwrap_err(), runs), ("second", 2));
    }
}
