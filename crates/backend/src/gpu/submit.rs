//! Frames of several filters on one device (a server's sessions) go to the device
//! together: each filter hands its frame's commands to [`Batcher::submit`], and whichever
//! caller finds no submission under way submits every command buffer waiting, its own and
//! those that arrived while the last submission was made, in one `Queue::submit`. A filter
//! alone submits at once; the batching costs it a lock.

use std::sync::{Condvar, Mutex, MutexGuard, PoisonError};

/// The device's submissions, batched.
#[derive(Debug, Default)]
pub(crate) struct Batcher {
    state: Mutex<State>,
    submitted: Condvar,
}

#[derive(Debug, Default)]
struct State {
    /// Command buffers waiting for the next submission.
    waiting: Vec<wgpu::CommandBuffer>,
    /// The number of that submission (from 0).
    next: u64,
    /// Whether a caller is submitting now.
    busy: bool,
    /// The last submission made: its number and index.
    last: Option<(u64, wgpu::SubmissionIndex)>,
    /// Submissions made, and command buffers in them.
    counts: (u64, u64),
}

/// Clears `busy` when the submitter is done, also when `Queue::submit` panics, so that the
/// callers waiting submit their own buffers rather than wait for ever.
struct Submitting<'a>(&'a Batcher);

impl Drop for Submitting<'_> {
    fn drop(&mut self) {
        self.0.lock().busy = false;
        self.0.submitted.notify_all();
    }
}

impl Batcher {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Submits `commands` with whatever else is waiting, through `queue`; the index of a
    /// submission that holds them (waiting for it waits for them).
    pub(crate) fn submit(&self, queue: &wgpu::Queue, commands: wgpu::CommandBuffer) -> wgpu::SubmissionIndex {
        self.submit_with(commands, |batch| queue.submit(batch))
    }

    /// [`Batcher::submit`] with the submission made by `submit`.
    fn submit_with(
        &self,
        commands: wgpu::CommandBuffer,
        submit: impl FnOnce(Vec<wgpu::CommandBuffer>) -> wgpu::SubmissionIndex,
    ) -> wgpu::SubmissionIndex {
        let mut state = self.lock();
        let mine = state.next;
        state.waiting.push(commands);
        let mut submit = Some(submit);
        loop {
            match &state.last {
                // Ours went in that submission or an earlier one.
                Some((number, index)) if *number >= mine => return index.clone(),
                _ => {}
            }
            if state.busy {
                state = self.submitted.wait(state).unwrap_or_else(PoisonError::into_inner);
                continue;
            }
            state.busy = true;
            let batch = std::mem::take(&mut state.waiting);
            let number = state.next;
            state.next += 1;
            drop(state);
            let guard = Submitting(self);
            let buffers = batch.len() as u64;
            let index = (submit.take().expect("one submission per caller"))(batch);
            {
                let mut s = self.lock();
                s.last = Some((number, index.clone()));
                s.counts.0 += 1;
                s.counts.1 += buffers;
            }
            drop(guard);
            return index;
        }
    }

    /// Submissions made so far, and the command buffers in them.
    #[cfg(test)]
    pub(crate) fn counts(&self) -> (u64, u64) {
        self.lock().counts
    }

    /// Command buffers waiting now.
    #[cfg(test)]
    fn waiting(&self) -> usize {
        self.lock().waiting.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// Frames that arrive while a submission is being made go to the device together, in
    /// the next one, and every caller gets an index that covers its own frame.
    #[test]
    fn frames_waiting_during_a_submission_go_in_one_batch() {
        let gpu = crate::gpu::shared().expect("these tests need an adapter (lavapipe serves)");
        let batcher = Arc::new(Batcher::default());
        let commands = || {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: 16,
                usage: wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.clear_buffer(&buffer, 0, None);
            enc.finish()
        };
        const OTHERS: usize = 5;
        std::thread::scope(|s| {
            // The first caller's submission waits until every other caller's frame waits.
            let first = {
                let (gpu, batcher) = (gpu.clone(), batcher.clone());
                let cmd = commands();
                s.spawn(move || {
                    batcher.submit_with(cmd, |batch| {
                        while batcher.waiting() < OTHERS {
                            std::thread::yield_now();
                        }
                        gpu.queue.submit(batch)
                    })
                })
            };
            while batcher.lock().last.is_none() && !batcher.lock().busy {
                std::thread::yield_now();
            }
            let others: Vec<_> = (0..OTHERS)
                .map(|_| {
                    let (gpu, batcher, cmd) = (gpu.clone(), batcher.clone(), commands());
                    s.spawn(move || batcher.submit(&gpu.queue, cmd))
                })
                .collect();
            let indices: Vec<_> = std::iter::once(first)
                .chain(others)
                .map(|t| t.join().unwrap())
                .collect();
            for index in indices {
                crate::gpu::wait(&gpu, Some(index)).unwrap();
            }
        });
        assert_eq!(batcher.counts(), (2, 1 + OTHERS as u64), "submissions, buffers");
        // Alone, a frame goes at once.
        batcher.submit(&gpu.queue, commands());
        assert_eq!(batcher.counts(), (3, 2 + OTHERS as u64));
    }
}
