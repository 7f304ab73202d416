# Sourced by the speed comparisons (tools/planner_speed.sh, tools/stack_speed.sh): another
# revision of this repository checked out beside it, to build and run against this tree.
#
#     old_tree ROOT OUT REV   # sets old_src to OUT/old-src, a detached worktree of ROOT at REV

old_tree() {
    old_src=$2/old-src
    if [ ! -d "$old_src" ]; then
        git -C "$1" worktree add --detach "$old_src" "$3" >/dev/null
    else
        git -C "$old_src" checkout --quiet --detach "$3"
    fi
}
