//! Locking shared by the tasks and the Zenoh callbacks.

use std::sync::{Mutex, MutexGuard, TryLockError};

/// Lock, and keep going if a holder panicked: every value skyfuse shares behind a mutex
/// (queues, counters, schedules) is valid after any single update, so a poisoned lock
/// holds usable data, and one panicking callback must not take the data path down.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// [`lock`] if nobody holds it now, else `None` (poisoned is taken as free, as there).
pub fn try_lock<T>(m: &Mutex<T>) -> Option<MutexGuard<'_, T>> {
    match m.try_lock() {
        Ok(g) => Some(g),
        Err(TryLockError::Poisoned(p)) => Some(p.into_inner()),
        Err(TryLockError::WouldBlock) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_poisoned_lock_still_gives_the_data() {
        let m = std::sync::Arc::new(Mutex::new(vec![1, 2]));
        let m2 = m.clone();
        let _ = std::thread::spawn(move || {
            let mut g = m2.lock().unwrap();
            g.push(3);
            panic!("holder panics");
        })
        .join();
        assert!(m.is_poisoned());
        assert_eq!(*lock(&m), vec![1, 2, 3]);
    }
}
