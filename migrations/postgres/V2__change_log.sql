-- salient's PostgreSQL schema, version 2: the change log replicas follow (issue #37).
--
-- A writing transaction takes the next position from `change_head` as its last statement.
-- The row stays locked until the transaction commits, so positions are handed out in commit
-- order: a replica that has read position p has seen every change before it. (A sequence
-- would not do: `nextval` is taken before commit, so a later commit can hold a smaller
-- number.)
CREATE TABLE change_head (
    only_row boolean PRIMARY KEY DEFAULT true CHECK (only_row),
    position bigint NOT NULL
);
INSERT INTO change_head (position) VALUES (0);

-- What changed at each position: a model (stored, re-described or deleted: a replica reads it
-- again) or a state key. Old entries are trimmed; a replica that fell behind them reloads.
CREATE TABLE changes (
    position bigint PRIMARY KEY,
    model_id text COLLATE "C",
    state_key text COLLATE "C",
    at timestamptz NOT NULL DEFAULT now(),
    CHECK ((model_id IS NULL) <> (state_key IS NULL))
);
