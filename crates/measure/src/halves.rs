//! Running two halves of a batch's distance queries at once, without this crate spawning a
//! thread (`isostream_pipeline` owns the threads and implements [`Halves`] with two).

/// Runs `a` and `b`, on two threads or one after the other: the measures are the same either
/// way (each half's distances are exact whatever runs it, and they are summed in order after).
pub trait Halves: Sync + Send + std::fmt::Debug {
    fn both(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send));
}

/// One thread: `a`, then `b`.
#[derive(Debug, Clone, Copy, Default)]
pub struct InTurn;

impl Halves for InTurn {
    fn both(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        a();
        b();
    }
}
