//! Opening a mosaic's inputs to plan it: many at once, in order.

use std::path::{Path, PathBuf};

/// Inputs whose headers are read at once while a mosaic is planned.
const OPENERS: usize = 16;

/// `open` of every input, in their order, up to [`OPENERS`] at once: an object in a
/// store answers in milliseconds to tens of them, so thousands opened one after
/// another would take minutes. Errors are as one after another would give: the first
/// failing input in order (no input is opened after one has failed).
pub(super) fn open_all<T: Send>(
    inputs: &[PathBuf],
    open: impl Fn(&Path) -> anyhow::Result<T> + Sync,
) -> anyhow::Result<Vec<T>> {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let workers = OPENERS.min(inputs.len());
    if workers <= 1 {
        return inputs.iter().map(|p| open(p)).collect();
    }
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let results: Vec<Mutex<Option<anyhow::Result<T>>>> =
        inputs.iter().map(|_| Mutex::new(None)).collect();
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                while !failed.load(Ordering::SeqCst) {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some(path) = inputs.get(i) else { break };
                    let r = open(path);
                    if r.is_err() {
                        failed.store(true, Ordering::SeqCst);
                    }
                    *results[i]
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(r);
                }
            });
        }
    });
    // Every input before a failed one was taken before it, so it is here.
    let mut out = Vec::with_capacity(inputs.len());
    for r in results {
        match r
            .into_inner()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
        {
            Some(r) => out.push(r?),
            None => unreachable!("an input after a failed one is never reached"),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_keep_the_inputs_order_and_the_first_failure_in_order_wins() {
        let inputs: Vec<PathBuf> = (0..100).map(|i| PathBuf::from(format!("{i}"))).collect();
        let number = |p: &Path| -> usize { p.to_str().unwrap().parse().unwrap() };
        let got = open_all(&inputs, |p| Ok(number(p) * 2)).unwrap();
        assert_eq!(got, (0..100).map(|i| i * 2).collect::<Vec<_>>());
        // Inputs 37 and 80 fail (80 may be opened before 37 finishes): 37 is named.
        let e = open_all(&inputs, |p| match number(p) {
            n @ (37 | 80) => {
                if n == 37 {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                anyhow::bail!("input {n} is broken")
            }
            n => Ok(n),
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "input 37 is broken");
        assert!(open_all::<u8>(&inputs[..1], |_| anyhow::bail!("one")).is_err());
    }
}
