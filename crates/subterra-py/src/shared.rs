//! Objects that Python threads may share.
//!
//! Every stateful class (a perception, a mapper, a planner, a navigator, a simulation) keeps its
//! core object behind a [`Shared`] lock: calls from several threads run one at a time, in the
//! order they get the lock, and none sees the object half-updated. A thread waiting for the
//! lock releases the GIL, so the thread holding it (which may itself have released the GIL for
//! a long update) always finishes.

use std::sync::{Mutex, MutexGuard, PoisonError, TryLockError};
use std::time::Duration;

use pyo3::Python;

/// How long a waiting thread sleeps, without the GIL, between attempts at the lock.
const WAIT: Duration = Duration::from_micros(50);

/// A core object behind a lock (see the module docs).
#[derive(Debug, Default)]
pub struct Shared<T>(Mutex<T>);

impl<T> Shared<T> {
    /// Wraps `value`.
    pub fn new(value: T) -> Self {
        Self(Mutex::new(value))
    }

    /// Locks, waiting with the GIL released while another thread holds the object. Must be
    /// called with the GIL held (every method of a Python class is). A panic while locked
    /// cannot leave the object behind (panics abort the call with an error, and the core's
    /// updates validate before they change state), so a poisoned lock is taken as it is.
    pub fn lock(&self) -> MutexGuard<'_, T> {
        loop {
            match self.0.try_lock() {
                Ok(guard) => return guard,
                Err(TryLockError::Poisoned(e)) => return e.into_inner(),
                Err(TryLockError::WouldBlock) => Python::attach(|py| py.detach(|| std::thread::sleep(WAIT))),
            }
        }
    }

    /// The value, consuming the lock.
    #[allow(dead_code)]
    pub fn into_inner(self) -> T {
        self.0.into_inner().unwrap_or_else(PoisonError::into_inner)
    }
}
