-- salient's PostgreSQL schema, version 1: what the sled store's trees hold (migrations/mod.rs,
-- versions 1–5), as tables. Ids and hashes sort byte-wise (COLLATE "C"), as sled's keys do, so
-- that a listing pages the same on both stores.

-- A model: its record (JSON, as the API shows it), the content hash of its upload and its
-- signature (salient_core::signature's binary form).
CREATE TABLE models (
    id text COLLATE "C" PRIMARY KEY,
    content_hash text COLLATE "C" NOT NULL,
    record jsonb NOT NULL,
    signature bytea NOT NULL
);

-- The model that last stored an upload with this content (on_duplicate).
CREATE TABLE content (
    content_hash text COLLATE "C" PRIMARY KEY,
    id text COLLATE "C" NOT NULL
);

-- Original files by SHA-256, shared between models and released with the last one.
CREATE TABLE blobs (
    hash text COLLATE "C" PRIMARY KEY,
    size bigint NOT NULL,
    refs bigint NOT NULL CHECK (refs > 0)
);

-- A file's bytes in chunks of 1 MiB: no row is a whole print file of hundreds of megabytes.
CREATE TABLE blob_chunks (
    hash text COLLATE "C" NOT NULL REFERENCES blobs ON DELETE CASCADE,
    seq integer NOT NULL,
    bytes bytea NOT NULL,
    PRIMARY KEY (hash, seq)
);
-- Mesh files are mostly compressed already (GLB, Draco, zip): keep them out of line, unpacked.
ALTER TABLE blob_chunks ALTER COLUMN bytes SET STORAGE EXTERNAL;

-- Data made from a model's upload (previews, patches): gone with the model.
CREATE TABLE derived (
    cache text NOT NULL,
    id text COLLATE "C" NOT NULL REFERENCES models ON DELETE CASCADE,
    entry bytea NOT NULL,
    PRIMARY KEY (cache, id)
);

-- Small values the service keeps between runs (a re-extraction's progress, dismissed pairs).
CREATE TABLE state (
    key text COLLATE "C" PRIMARY KEY,
    value bytea NOT NULL
);
