//! Lazy edge evaluation: a successor is queued on the cheap tests alone, with its candidate
//! leg set, and the steps that lead to it are proven (the swept-motion proof per leg
//! configuration, [`Search::valid_subset`]) only when it is popped, or when another node's
//! dominance at the same pose cannot be decided without its valid set. Most successors are
//! never popped, so most proofs are never run.
//!
//! # Why the search does exactly what it did when it proved every successor at once
//!
//! Call a node *generated* when an expansion's cheap tests (give-up distance, arena, step
//! limit, a candidate set not empty) let it through, and let `V(X)` be its valid set: the
//! candidates some member of the parent's set reaches by a step the simulator accepts. Say
//! that `N` *beats* `X` (two nodes at one pose) when `g(N) <= g(X)`, `V(X) ⊆ V(N)`, and, if both
//! are equal, `N` was generated first. That is a strict partial order. The search that proves
//! every successor at once (call it eager) drops a new node when a known live node dominates
//! it, and retires the known nodes the new one dominates; by induction over its steps, a node
//! is dead in it at time `t` exactly when `V(X)` is empty or some node generated before `t` with
//! a non-empty valid set beats it (a chain of beaten nodes ends in a live one, which beats `X`
//! by transitivity, and either dropped `X` or retired it). That description does not depend on
//! when the valid sets were computed, only on which nodes were generated.
//!
//! This search decides the same predicate, at the only moments it matters: when a node is
//! popped at the priority eager would have queued it at (whether it is expanded), and when a
//! goal is generated (whether it is accepted at once). [`Search::survives`] first proves, for
//! every node at the pose not yet proven that could beat the one being decided (no more
//! steps, candidates holding its valid set), the steps to the members of that valid set (the
//! rest only when the tie needs them), then looks for one that does. Nodes are
//! dropped or retired earlier only when beaten for sure: a candidate set inside a known valid
//! set is beaten, and a known valid set beats a candidate set inside it (the tie, equal sets
//! and steps, is left for the proof). So the nodes expanded, in order, their sets, the goal
//! accepted and the plan rebuilt are eager's; only the number of proofs changes. The queue
//! order is eager's too: a node's priority is its steps plus the weighted bound, the exact
//! search's bound depends on the pose alone, and the weighted search's leg hint is a minimum
//! over the set, so a node queued on its candidates is popped no later than eager would pop it,
//! and goes back at eager's priority when its valid set raises the hint (the loop in
//! [`Search::run`]). Ties go by generation order, which both searches share.
//!
//! In particular the exact search's proven shortest lengths are unchanged; the usual lazy A*
//! argument gives that too (a queued node on a shortest plan carries its configuration, and
//! proving it cannot remove it), but the argument above gives the expansion counts as well.

use super::legs::LegSet;
use super::moves::PoseKey;
use super::search::Node;
use super::search::Search;

/// Whether `n` (index `ni`) surely beats `x` (index `xi`) at the same pose, on what is known of
/// them: `n` must be evaluated; for `x` its candidate set stands in for its valid set when it is
/// not, which decides all but the tie (equal steps, `x`'s candidates equal to `n`'s valid set,
/// `n` the newer), where `x`'s valid set might equal `n`'s and then `x` would win.
fn beats(n: &Node, ni: u32, x: &Node, xi: u32) -> bool {
    n.evaluated
        && n.steps <= x.steps
        && x.legs.is_subset_of(&n.legs)
        && (n.steps < x.steps || x.legs != n.legs || ni < xi)
}

impl Search<'_> {
    /// Whether a node already proven at the pose has no more steps and a superset of `legs`:
    /// a new node with these candidates would be beaten (it is the newest), so it is not made.
    pub(super) fn is_dominated(&self, key: PoseKey, steps: u32, legs: &LegSet) -> bool {
        self.seen.get(&key).is_some_and(|known| {
            known.iter().any(|&k| {
                let n = &self.nodes[k as usize];
                n.evaluated && n.steps <= steps && legs.is_subset_of(&n.legs)
            })
        })
    }

    /// Whether a proven node at the pose surely beats `node` (then dead): for a node not yet
    /// proven, one proven since it was queued spares its proof.
    pub(super) fn surely_beaten(&mut self, node: u32) -> bool {
        let key = self.nodes[node as usize].pose.key();
        let x = &self.nodes[node as usize];
        let beaten = self.seen.get(&key).is_some_and(|known| {
            known
                .iter()
                .any(|&k| k != node && beats(&self.nodes[k as usize], k, x, node))
        });
        if beaten {
            self.nodes[node as usize].dead = true;
            self.forget(key, node);
        }
        beaten
    }

    /// Proves the steps to `node` from its parent's set, replacing its candidates by its valid
    /// set; false (and the node dead) when no configuration is reachable. Retires the nodes at
    /// the pose it surely beats: they are dead in eager whatever happens to this one.
    pub(super) fn evaluate(&mut self, node: u32) -> bool {
        self.prove(node, None)
    }

    /// As [`Search::evaluate`], but with `up_to`, the priority `node` was popped at, it may
    /// stop early: once the configurations refuted so far raise its priority above `up_to`
    /// (the weighted search's leg hint), the node goes back to the queue with the rest
    /// unproven. It proves first the configurations that hold the hint down
    /// ([`super::heuristic::LegHint::holding`]), so a node whose hint rises costs few proofs.
    /// The node's set stays a superset of its valid set throughout, so it counts as candidates
    /// for dominance until every configuration is decided.
    pub(super) fn prove(&mut self, node: u32, up_to: Option<f32>) -> bool {
        let pose = self.nodes[node as usize].pose;
        loop {
            let (left, proven, h) = {
                let n = &self.nodes[node as usize];
                (n.legs, n.proven, n.h)
            };
            let unknown = left.difference(&proven);
            if unknown.is_empty() {
                return true;
            }
            // What is refuted so far (here, or by a rival's proof since the node was queued)
            // may have lifted it above the priority it was popped at.
            if up_to.is_some_and(|f| self.priority(node) > f) {
                return true;
            }
            let batch = match (&self.leg_hint, up_to) {
                (Some(hint), Some(_)) => hint
                    .holding(&pose, self.env.target(), &left, &proven, h)
                    .unwrap_or(unknown),
                _ => unknown,
            };
            if !self.decide(node, &batch) {
                return false;
            }
        }
    }

    /// Proves the steps to the members of `cells` in `node`'s set not decided yet, and drops
    /// the refuted ones from it; false (and the node dead) when nothing is left. Once every
    /// member is decided the node is evaluated, and retires the nodes at the pose it surely
    /// beats: they are dead in eager whatever happens to this one.
    fn decide(&mut self, node: u32, cells: &LegSet) -> bool {
        let (parent, m, pose, left, proven) = {
            let n = &self.nodes[node as usize];
            (n.parent, n.base_move as usize, n.pose, n.legs, n.proven)
        };
        let key = pose.key();
        let batch = cells.intersection(&left).difference(&proven);
        if !batch.is_empty() {
            let (from, legs) = {
                let p = &self.nodes[parent as usize];
                (p.pose, p.legs)
            };
            let valid = self.valid_subset(&from, &legs, m, &pose, key, &batch);
            self.evaluations += 1;
            let n = &mut self.nodes[node as usize];
            n.proven.union_with(&valid);
            n.legs = left.difference(&batch.difference(&valid));
            if n.legs.is_empty() {
                n.dead = true;
                self.forget(key, node);
                return false;
            }
        }
        let n = &mut self.nodes[node as usize];
        if n.evaluated || n.legs != n.proven {
            return true;
        }
        n.evaluated = true;
        let Some(known) = self.seen.get_mut(&key) else {
            return true;
        };
        let nodes = &mut self.nodes;
        known.retain(|&k| {
            let beaten = k != node && beats(&nodes[node as usize], node, &nodes[k as usize], k);
            nodes[k as usize].dead |= beaten;
            !beaten
        });
        true
    }

    /// Whether the evaluated `node` is live: no node at its pose generated so far beats it.
    /// Proves first, for every unproven node there that might (no more steps, its candidates
    /// holding this node's valid set), the steps to the members of this node's set; false,
    /// and the node dead, when beaten.
    pub(super) fn survives(&mut self, node: u32) -> bool {
        let key = self.nodes[node as usize].pose.key();
        let Some(known) = self.seen.get(&key) else {
            return !self.nodes[node as usize].dead;
        };
        let x = &self.nodes[node as usize];
        let rivals: Vec<u32> = known
            .iter()
            .copied()
            .filter(|&k| {
                let n = &self.nodes[k as usize];
                k != node
                    && !n.evaluated
                    && n.steps <= x.steps
                    && x.legs.is_subset_of(&n.legs)
                    // Newer, as many steps, candidates no more than this set: it cannot win.
                    && !(n.steps == x.steps && k > node && n.legs == x.legs)
            })
            .collect();
        let valid = self.nodes[node as usize].legs;
        let steps = self.nodes[node as usize].steps;
        for k in rivals {
            if self.nodes[node as usize].dead {
                return false;
            }
            // A rival retired meanwhile by another rival is beaten by that one as well.
            if self.nodes[k as usize].dead {
                continue;
            }
            // It beats this node only if every member of this node's set is valid there: its
            // other members need no proof unless the two sets might be equal and it is the
            // newer at as many steps.
            if !self.decide(k, &valid) || !valid.is_subset_of(&self.nodes[k as usize].proven) {
                continue;
            }
            if self.nodes[k as usize].steps < steps || k < node {
                self.nodes[node as usize].dead = true;
                self.forget(key, node);
                return false;
            }
            self.evaluate(k);
        }
        !self.nodes[node as usize].dead && !self.surely_beaten(node)
    }

    /// Removes a dead node from its pose's list.
    fn forget(&mut self, key: PoseKey, node: u32) {
        if let Some(known) = self.seen.get_mut(&key) {
            known.retain(|&k| k != node);
        }
    }
}
