//! A stream produced on a thread of its own, a bounded number of items
//! ahead of its consumer: on two cores, decoding a Parquet file and using
//! its batches take the longer of the two instead of their sum (the join,
//! the fleet report's passes). The items keep their order.
//!
//! The producer ends its items with an end marker (`None`), so a producer
//! that stops without it — a decoder that panics on a damaged page — ends
//! the stream with an error, never with a silently shorter one.

use std::sync::mpsc::{sync_channel, Receiver};

use crate::{Error, Result};

/// The items a producer sent down `rx` until its end marker; when the
/// sender is gone without one, a last item: `stopped()`'s error. A
/// consumer that drops the iterator makes the producer's next send fail,
/// which is its cue to stop.
pub fn received<T>(
    rx: Receiver<Option<Result<T>>>,
    stopped: impl Fn() -> Error,
) -> impl Iterator<Item = Result<T>> {
    let mut ended = false;
    std::iter::from_fn(move || {
        if ended {
            return None;
        }
        match rx.recv() {
            Ok(Some(item)) => Some(item),
            Ok(None) => {
                ended = true;
                None
            }
            Err(_) => {
                ended = true;
                Some(Err(stopped()))
            }
        }
    })
}

/// The items of `it`, produced on a thread of their own at most `depth`
/// ahead of the consumer ([`received`]).
pub fn produced_ahead<T: Send + 'static>(
    it: impl Iterator<Item = Result<T>> + Send + 'static,
    depth: usize,
    stopped: impl Fn() -> Error,
) -> impl Iterator<Item = Result<T>> {
    let (tx, rx) = sync_channel::<Option<Result<T>>>(depth);
    std::thread::spawn(move || {
        for item in it {
            if tx.send(Some(item)).is_err() {
                return;
            }
        }
        let _ = tx.send(None);
    });
    received(rx, stopped)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Items produced ahead arrive all and in order; a producer that dies
    /// half way ends the stream with the error, not a shorter stream.
    #[test]
    fn items_arrive_in_order_or_the_stream_fails_loudly() {
        let stopped = || crate::err!("t.parquet: stopped before the end");
        let got: Vec<i64> = produced_ahead((0..10).map(Ok), 2, stopped)
            .map(|v| v.unwrap())
            .collect();
        assert_eq!(got, (0..10).collect::<Vec<_>>());
        let dying = (0..10).map(|i| if i < 3 { Ok(i) } else { panic!("decoder died") });
        let got: Vec<Result<i64>> = produced_ahead(dying, 2, stopped).collect();
        assert_eq!(got.len(), 4);
        assert!(got[..3].iter().all(|v| v.is_ok()));
        let e = got[3].as_ref().unwrap_err().to_string();
        assert!(
            e.contains("t.parquet") && e.contains("stopped before the end"),
            "{e}"
        );
    }
}
