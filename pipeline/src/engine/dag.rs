//! Edges from declared inputs and outputs; topological order.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use crate::bail;

use crate::error::Result;
use crate::traits::Stage;

/// Stages sorted so every stage comes after the producers of the artifacts it
/// reads (Kahn's algorithm; ties broken by declaration order, so the order is
/// deterministic).
pub fn topological_order(stages: &[Arc<dyn Stage>]) -> Result<Vec<Arc<dyn Stage>>> {
    let mut producer: BTreeMap<&str, usize> = BTreeMap::new();
    for (i, s) in stages.iter().enumerate() {
        for w in s.writes() {
            if let Some(j) = producer.insert(w, i) {
                bail!(
                    "artifact `{w}` is written by two stages: `{}` and `{}`",
                    stages[j].name(),
                    s.name()
                );
            }
        }
    }
    let n = stages.len();
    let mut deps: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); n];
    for (i, s) in stages.iter().enumerate() {
        for r in s.reads_artifacts() {
            match producer.get(r) {
                Some(&j) if j != i => {
                    deps[i].insert(j);
                }
                Some(_) => bail!("stage `{}` reads its own output `{r}`", s.name()),
                None => bail!(
                    "stage `{}` reads artifact `{r}`, which no stage writes",
                    s.name()
                ),
            }
        }
    }
    let mut done = vec![false; n];
    let mut order = Vec::with_capacity(n);
    while order.len() < n {
        let next = (0..n).find(|&i| !done[i] && deps[i].iter().all(|&d| done[d]));
        match next {
            Some(i) => {
                done[i] = true;
                order.push(stages[i].clone());
            }
            None => {
                let stuck: Vec<&str> = (0..n)
                    .filter(|&i| !done[i])
                    .map(|i| stages[i].name())
                    .collect();
                bail!("the stages form a cycle: {}", stuck.join(", "));
            }
        }
    }
    Ok(order)
}

/// The target stages plus every stage they (transitively) depend on, in
/// topological order.
pub fn with_upstream(
    ordered: &[Arc<dyn Stage>],
    targets: &BTreeSet<String>,
) -> Vec<Arc<dyn Stage>> {
    let mut needed: BTreeSet<String> = targets.clone();
    // Walk backwards: a needed stage makes the producers of its inputs needed.
    for s in ordered.iter().rev() {
        if needed.contains(s.name()) {
            for r in s.reads_artifacts() {
                if let Some(p) = ordered.iter().find(|p| p.writes().contains(r)) {
                    needed.insert(p.name().to_string());
                }
            }
        }
    }
    ordered
        .iter()
        .filter(|s| needed.contains(s.name()))
        .cloned()
        .collect()
}
