//! Layout checks: no import cycles between modules, and the README's `## Layout` table.
//!
//! Types live in leaf modules and each module only uses modules "below" it, so a reader can
//! follow the layering from any file without meeting the same module twice. A cycle means two
//! modules can only be understood together: move the shared type to a leaf (or to one side).
//!
//! [`module_cycles`] checks this from the source text alone (std only, no parser). Written
//! here rather than run as `cargo-modules --acyclic`: that tool builds on rust-analyzer, minutes
//! of compiling on CI's two cores for every run, and follows its toolchain; these rules need
//! only the module tree and the paths in it.
//!
//! 1. **Tree.** Starting at the crate root (`lib.rs` / `main.rs`, path `[]`), a module `a`
//!    declared with `mod a;` (any visibility, any attributes) lives in `DIR/a.rs` or
//!    `DIR/a/mod.rs`, and its own children in `DIR/a/`. Files nobody declares, `#[path]`
//!    modules and inline `mod x { … }` are not modules of the tree (inline ones belong to their
//!    file).
//! 2. **Text.** Comments (line, doc and block), string and char literals are ignored, and so is
//!    everything from a `#[cfg(test)]` followed by `mod tests {` / `mod test {` to the end of
//!    the file: tests may import freely (a `#[cfg(test)] mod tests;` is not a module either).
//! 3. **References.** Every `use` (grouped, nested, multi-line, `as`, `*`), and every path in
//!    code, that starts with `crate::`, `self::`, `super::` (repeated) or with a child module
//!    declared in the same file (`mod columns; … columns::Row`); a parent's `pub use
//!    child::X` uses the child too. Anything else (`std::`, `serde::`, local names) is outside
//!    the crate or inside the file, and is ignored.
//! 4. **Targets.** A reference resolves to the deepest module it names (`crate::a::b::Item` →
//!    `a::b`). When the next segment is not a module but a name that module's file imports
//!    (`pub use error::Error;` in `lib.rs`, or any `use`, since children see private imports
//!    too), the reference follows that import to where the item is defined: `use crate::Error`
//!    depends on `error`, not on the root. Otherwise the item is defined in that module's own
//!    file.
//! 5. **Levels.** A reference from module `S` to module `T` is an edge at level `L`, their
//!    longest common prefix, between the children of `L` containing `S` and `T`: every level
//!    is its own graph over its children, so `a::x -> b::y` is only `a -> b` at the root. A
//!    module and the modules it declares are one unit, and references between them are no
//!    edge: a parent declares and re-exports its children, and they share its items (a trait
//!    and its implementations, a handler and the service state). Across siblings, a cycle means
//!    two modules that can only be read together.
//! 6. **Cycles.** Each strongly connected component of a level's graph is one cycle: a
//!    concrete cycle (a pair using each other if there is one) with, per edge, the number of
//!    references and the first one (`file:line` `path`); for a larger component, its nodes and
//!    its other pairs using each other. The list is sorted.
//!
//! [`layout_table_paths`] reads the paths of the README's layout table, for checking that each
//! exists and each module is described.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fs;
use std::path::Path;

/// Every cycle among the modules of the crate whose root file is `root` (a `lib.rs` or
/// `main.rs`), one string per cycle, e.g. "at `crate::api`: state -> search -> state" followed
/// by one indented line per edge with an example reference. Empty when acyclic.
pub fn module_cycles(root: &Path) -> Vec<String> {
    let dir = root.parent().unwrap_or_else(|| Path::new("."));
    let mut tree = BTreeMap::new();
    load(&mut tree, Vec::new(), root, dir, dir);
    let mut levels: BTreeMap<Vec<String>, Graph> = BTreeMap::new();
    for (path, module) in &tree {
        for reference in references(module) {
            let Some(absolute) = absolute(&tree, path, &reference.path) else {
                continue;
            };
            let target = defining_module(&tree, absolute, 0);
            if &target == path {
                continue;
            }
            let common = path.iter().zip(&target).take_while(|(a, b)| a == b).count();
            let node = |p: &[String]| p.get(common).cloned();
            // A module and the modules it declares are one unit (rule 5): only siblings count.
            if node(path).is_none() || node(&target).is_none() {
                continue;
            }
            let edge = levels
                .entry(path[..common].to_vec())
                .or_default()
                .entry((node(path), node(&target)))
                .or_insert_with(|| Edge {
                    count: 0,
                    example: format!(
                        "{}:{} `{}`",
                        module.file,
                        reference.line,
                        reference.path.join("::")
                    ),
                });
            edge.count += 1;
        }
    }
    let mut cycles: Vec<String> = levels
        .iter()
        .flat_map(|(level, graph)| cycles_at(level, graph))
        .collect();
    cycles.sort();
    cycles
}

/// The paths named in the first column of the Markdown table that follows the heading
/// `## Layout` in `readme` (backticked cells like `src/mesh/load/`, possibly several per cell
/// separated by commas, e.g. "`src/mesh/weld.rs`, `orient.rs`" where a bare file name is
/// relative to the directory of the previous path in that cell).
pub fn layout_table_paths(readme: &str) -> Vec<String> {
    let mut lines = readme
        .lines()
        .skip_while(|line| line.trim_end() != "## Layout")
        .skip(1)
        .take_while(|line| !line.starts_with('#'))
        .skip_while(|line| !line.trim_start().starts_with('|'))
        .take_while(|line| line.trim_start().starts_with('|'));
    lines.next(); // the header row
    let mut paths = Vec::new();
    for row in lines {
        let cell = row.trim_start()[1..].split('|').next().unwrap_or("");
        if cell.trim().chars().all(|c| matches!(c, '-' | ':' | ' ')) {
            continue; // the separator row
        }
        let mut dir = String::new();
        for name in cell.split('`').skip(1).step_by(2) {
            let path = if name.contains('/') {
                name.to_string()
            } else {
                format!("{dir}{name}")
            };
            dir = match path.rfind('/') {
                Some(end) => path[..=end].to_string(),
                None => String::new(),
            };
            paths.push(path);
        }
    }
    paths
}

/// A source file of the tree, already reduced to the tokens that matter.
struct Module {
    /// The file, relative to the crate root's directory, with `/`.
    file: String,
    /// Child modules declared in the file that have a file of their own.
    children: BTreeSet<String>,
    tokens: Vec<Token>,
    /// Every leaf of every `use` in the file.
    imports: Vec<Import>,
    /// Token ranges of the `use` declarations.
    uses: Vec<(usize, usize)>,
}

type Tree = BTreeMap<Vec<String>, Module>;

/// A node of a level's graph: `None` is the level's own file (`self`), `Some` a child.
type Node = Option<String>;

type Graph = BTreeMap<(Node, Node), Edge>;

struct Edge {
    count: usize,
    example: String,
}

struct Token {
    text: String,
    line: usize,
}

/// One leaf of a `use` tree: `use a::{b::C as D, e::*}` has `a::b::C` named `D` and `a::e`
/// glob (no name).
struct Import {
    path: Vec<String>,
    name: Option<String>,
    line: usize,
}

/// A path as written in a file.
struct Reference {
    path: Vec<String>,
    line: usize,
}

fn load(tree: &mut Tree, path: Vec<String>, file: &Path, children_dir: &Path, crate_dir: &Path) {
    let source = fs::read_to_string(file).unwrap_or_default();
    let tokens = tokenize(&without_tests(&source));
    let (imports, uses) = parse_uses(&tokens);
    let mut children = BTreeSet::new();
    for name in declared_modules(&tokens) {
        let dir = children_dir.join(&name);
        let flat = children_dir.join(format!("{name}.rs"));
        let nested = dir.join("mod.rs");
        let child_file = if flat.is_file() {
            flat
        } else if nested.is_file() {
            nested
        } else {
            continue;
        };
        let mut child = path.clone();
        child.push(name.clone());
        load(tree, child, &child_file, &dir, crate_dir);
        children.insert(name);
    }
    let relative = file.strip_prefix(crate_dir).unwrap_or(file);
    let file = relative
        .components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/");
    tree.insert(
        path,
        Module {
            file,
            children,
            tokens,
            imports,
            uses,
        },
    );
}

/// `source` without its unit tests: from a `#[cfg(test)]` line whose next line (blank lines
/// and attributes aside) opens `mod tests {` or `mod test {`, to the end. A
/// `#[cfg(test)] mod tests;` loses only its declaration. Line numbers are kept.
fn without_tests(source: &str) -> String {
    let lines: Vec<&str> = source.lines().collect();
    let mut kept: Vec<&str> = Vec::with_capacity(lines.len());
    let mut i = 0;
    while i < lines.len() {
        if lines[i].trim() == "#[cfg(test)]" {
            let mut j = i + 1;
            while j < lines.len()
                && (lines[j].trim().is_empty() || lines[j].trim().starts_with("#["))
            {
                j += 1;
            }
            let next = lines.get(j).map_or("", |line| line.trim());
            let next = next.strip_prefix("pub ").unwrap_or(next);
            let rest = next
                .strip_prefix("mod tests")
                .or_else(|| next.strip_prefix("mod test"))
                .map(str::trim_start);
            match rest {
                Some(rest) if rest.starts_with('{') => break,
                Some(rest) if rest.starts_with(';') => {
                    kept.extend(std::iter::repeat_n("", j + 1 - i));
                    i = j + 1;
                    continue;
                }
                _ => {}
            }
        }
        kept.push(lines[i]);
        i += 1;
    }
    kept.join("\n")
}

/// Identifiers, `::` and single punctuation characters, with their lines; comments, string,
/// char and number literals and lifetimes dropped.
fn tokenize(source: &str) -> Vec<Token> {
    let chars: Vec<char> = source.chars().collect();
    let at = |k: usize| chars.get(k).copied().unwrap_or('\0');
    let ident_start = |c: char| c.is_alphabetic() || c == '_';
    let ident_char = |c: char| c.is_alphanumeric() || c == '_';
    let mut tokens = Vec::new();
    let mut line = 1;
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let start = i;
        if c == '/' && at(i + 1) == '/' {
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && at(i + 1) == '*' {
            let mut depth = 0;
            loop {
                if i >= chars.len() {
                    break;
                } else if chars[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    i += 2;
                } else if chars[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if let Some(end) = string_end(&chars, i) {
            i = end;
        } else if c == '\'' {
            if at(i + 1) == '\\' {
                i += 3;
                while i < chars.len() && chars[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if at(i + 2) == '\'' {
                i += 3;
            } else {
                i += 1;
                while ident_char(at(i)) {
                    i += 1;
                }
            }
        } else if ident_start(c) {
            if c == 'r' && at(i + 1) == '#' && ident_start(at(i + 2)) {
                i += 2;
            }
            let first = i;
            while ident_char(at(i)) {
                i += 1;
            }
            tokens.push(Token {
                text: chars[first..i].iter().collect(),
                line,
            });
        } else if c.is_ascii_digit() {
            while ident_char(at(i)) {
                i += 1;
            }
        } else if c == ':' && at(i + 1) == ':' {
            tokens.push(Token {
                text: "::".to_string(),
                line,
            });
            i += 2;
        } else {
            if !c.is_whitespace() {
                tokens.push(Token {
                    text: c.to_string(),
                    line,
                });
            }
            i += 1;
        }
        line += chars[start..i.min(chars.len())]
            .iter()
            .filter(|&&c| c == '\n')
            .count();
    }
    tokens
}

/// Where the string literal starting at `i` (`"…"`, `b"…"`, `c"…"`, `r#"…"#`, `br"…"`, …)
/// ends, if one does.
fn string_end(chars: &[char], i: usize) -> Option<usize> {
    let at = |k: usize| chars.get(k).copied().unwrap_or('\0');
    let mut j = i;
    if matches!(at(j), 'b' | 'c') {
        j += 1;
    }
    if at(j) == 'r' {
        j += 1;
        let mut hashes = 0;
        while at(j) == '#' {
            hashes += 1;
            j += 1;
        }
        if at(j) != '"' {
            return None;
        }
        j += 1;
        while j < chars.len() {
            if chars[j] == '"' && (1..=hashes).all(|h| at(j + h) == '#') {
                return Some(j + 1 + hashes);
            }
            j += 1;
        }
        return Some(chars.len());
    }
    if at(j) != '"' {
        return None;
    }
    j += 1;
    while j < chars.len() {
        match chars[j] {
            '\\' => j += 2,
            '"' => return Some(j + 1),
            _ => j += 1,
        }
    }
    Some(chars.len())
}

/// The names of `mod name;` declarations, except `#[path = …]` ones.
fn declared_modules(tokens: &[Token]) -> Vec<String> {
    let text = |k: usize| tokens.get(k).map_or("", |t| t.text.as_str());
    let mut names = Vec::new();
    for i in 0..tokens.len() {
        if text(i) != "mod" || text(i + 2) != ";" || !is_ident(text(i + 1)) {
            continue;
        }
        let item_start = (0..i)
            .rev()
            .find(|&k| matches!(text(k), ";" | "{" | "}"))
            .map_or(0, |k| k + 1);
        let has_path = (item_start..i).any(|k| text(k) == "path" && text(k.wrapping_sub(1)) == "[");
        if !has_path {
            names.push(text(i + 1).to_string());
        }
    }
    names
}

fn is_ident(text: &str) -> bool {
    text.chars()
        .next()
        .is_some_and(|c| c.is_alphabetic() || c == '_')
}

/// The leaves of every `use` declaration, and the token range each declaration spans.
fn parse_uses(tokens: &[Token]) -> (Vec<Import>, Vec<(usize, usize)>) {
    let mut imports = Vec::new();
    let mut ranges = Vec::new();
    let mut i = 0;
    while i < tokens.len() {
        if tokens[i].text == "use" {
            let end = parse_use_tree(tokens, i + 1, Vec::new(), &mut imports);
            ranges.push((i, end));
            i = end.max(i + 1);
        } else {
            i += 1;
        }
    }
    (imports, ranges)
}

/// Parses one use tree starting at `i` under `prefix`, pushing its leaves; returns the index
/// after it.
fn parse_use_tree(
    tokens: &[Token],
    mut i: usize,
    prefix: Vec<String>,
    out: &mut Vec<Import>,
) -> usize {
    let text = |k: usize| tokens.get(k).map_or("", |t| t.text.as_str());
    let mut path = prefix;
    if text(i) == "::" {
        // `::name` is always an external crate.
        path.push("::".to_string());
        i += 1;
    }
    loop {
        match text(i) {
            "{" => {
                i += 1;
                while i < tokens.len() && text(i) != "}" {
                    let next = parse_use_tree(tokens, i, path.clone(), out);
                    i = if next == i { i + 1 } else { next };
                    if text(i) == "," {
                        i += 1;
                    }
                }
                return i + 1;
            }
            "*" => {
                out.push(Import {
                    path,
                    name: None,
                    line: tokens[i].line,
                });
                return i + 1;
            }
            segment if is_ident(segment) => {
                let line = tokens[i].line;
                if segment != "self" || path.is_empty() {
                    path.push(segment.to_string());
                }
                i += 1;
                if text(i) == "::" {
                    i += 1;
                    continue;
                }
                let mut name = path.last().cloned();
                if text(i) == "as" {
                    name = Some(text(i + 1).to_string()).filter(|n| n != "_");
                    i += 2;
                }
                out.push(Import { path, name, line });
                return i;
            }
            _ => return i,
        }
    }
}

/// Every path of `module` that may name a module of the crate: the `use` leaves, and the
/// paths in code starting with `crate`, `self`, `super` or a child module.
fn references(module: &Module) -> Vec<Reference> {
    let tokens = &module.tokens;
    let text = |k: usize| tokens.get(k).map_or("", |t| t.text.as_str());
    let mut references: Vec<Reference> = module
        .imports
        .iter()
        .map(|import| Reference {
            path: import.path.clone(),
            line: import.line,
        })
        .collect();
    let mut uses = module.uses.iter().peekable();
    let mut i = 0;
    while i < tokens.len() {
        if let Some(&&(start, end)) = uses.peek() {
            if i >= start {
                i = i.max(end);
                uses.next();
                continue;
            }
        }
        let first = text(i);
        let starts_path =
            matches!(first, "crate" | "self" | "super") || module.children.contains(first);
        let continues_path = i > 0 && text(i - 1) == "::";
        let visibility = i > 0 && text(i - 1) == "in";
        if !starts_path || continues_path || visibility || text(i + 1) != "::" {
            i += 1;
            continue;
        }
        let line = tokens[i].line;
        let mut segments = vec![first.to_string()];
        i += 1;
        while text(i) == "::" && is_ident(text(i + 1)) {
            segments.push(text(i + 1).to_string());
            i += 2;
        }
        references.push(Reference {
            path: segments,
            line,
        });
    }
    references
}

/// `path` as written in module `from`, from the crate root; `None` outside the crate.
fn absolute(tree: &Tree, from: &[String], path: &[String]) -> Option<Vec<String>> {
    let first = path.first()?;
    match first.as_str() {
        "crate" => Some(path[1..].to_vec()),
        "self" => Some([from, &path[1..]].concat()),
        "super" => {
            let ups = path.iter().take_while(|s| *s == "super").count();
            let base = from.len().checked_sub(ups)?;
            Some([&from[..base], &path[ups..]].concat())
        }
        _ if tree.get(from)?.children.contains(first) => Some([from, path].concat()),
        _ => None,
    }
}

/// The module where the thing `path` (from the root) names is defined: its deepest module
/// prefix, or, when the name after it is imported by that module's file, where the import
/// leads.
fn defining_module(tree: &Tree, path: Vec<String>, depth: usize) -> Vec<String> {
    let mut module = Vec::new();
    let mut rest = path.iter();
    let mut next = rest.next();
    while let Some(segment) = next {
        if !tree
            .get(&module)
            .is_some_and(|m| m.children.contains(segment))
        {
            break;
        }
        module.push(segment.clone());
        next = rest.next();
    }
    let (Some(name), Some(file)) = (next, tree.get(&module)) else {
        return module;
    };
    let import = file.imports.iter().find(|i| i.name.as_ref() == Some(name));
    match import.and_then(|i| absolute(tree, &module, &i.path)) {
        Some(mut target) if depth < 16 => {
            target.extend(rest.cloned());
            defining_module(tree, target, depth + 1)
        }
        _ => module,
    }
}

/// The cycles of one level's graph, one per strongly connected component, formatted.
fn cycles_at(level: &[String], graph: &Graph) -> Vec<String> {
    let mut next: BTreeMap<&Node, BTreeSet<&Node>> = BTreeMap::new();
    for (from, to) in graph.keys() {
        next.entry(from).or_default().insert(to);
        next.entry(to).or_default();
    }
    let reach = |start: &Node| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![start];
        while let Some(node) = stack.pop() {
            for &to in &next[node] {
                if seen.insert(to) {
                    stack.push(to);
                }
            }
        }
        seen
    };
    let reaches: BTreeMap<&Node, BTreeSet<&Node>> =
        next.keys().map(|&node| (node, reach(node))).collect();
    let mut done = BTreeSet::new();
    let mut found = Vec::new();
    for (&node, reached) in &reaches {
        if done.contains(node) || !reached.contains(node) {
            continue;
        }
        let component: BTreeSet<&Node> = reached
            .iter()
            .copied()
            .filter(|other| reaches[other].contains(node))
            .collect();
        done.extend(component.iter().copied());
        found.push(describe(level, graph, &next, &component));
    }
    found
}

/// The shortest path from `start` to `end` (breadth first, in node order), both included.
fn shortest_path<'a>(
    start: &'a Node,
    end: &'a Node,
    next: &BTreeMap<&'a Node, BTreeSet<&'a Node>>,
) -> Vec<&'a Node> {
    let mut parent: BTreeMap<&Node, &Node> = BTreeMap::new();
    let mut queue = VecDeque::from([start]);
    while let Some(node) = queue.pop_front() {
        if node == end {
            break;
        }
        for &to in &next[node] {
            if to != start && !parent.contains_key(to) {
                parent.insert(to, node);
                queue.push_back(to);
            }
        }
    }
    let mut path = vec![end];
    let mut at = end;
    while at != start {
        at = parent[at];
        path.push(at);
    }
    path.reverse();
    path
}

/// One component: a concrete cycle (its first pair of nodes using each other, or else the
/// shortest cycle through its first node) with an example per edge, then, when the component
/// is larger, its nodes and its other pairs using each other.
fn describe(
    level: &[String],
    graph: &Graph,
    next: &BTreeMap<&Node, BTreeSet<&Node>>,
    component: &BTreeSet<&Node>,
) -> String {
    let name = |node: &Node| node.clone().unwrap_or_else(|| "self".to_string());
    let example = |from: &Node, to: &Node| {
        let edge = &graph[&(from.clone(), to.clone())];
        match edge.count {
            1 => edge.example.clone(),
            n => format!("{} (+{} more)", edge.example, n - 1),
        }
    };
    let pairs: Vec<(&Node, &Node)> = component
        .iter()
        .flat_map(|&a| next[a].iter().map(move |&b| (a, b)))
        .filter(|&(a, b)| a < b && next[b].contains(a))
        .collect();
    let first = component.first().copied().unwrap_or(&None);
    let cycle = match pairs.first() {
        Some(&(a, b)) => vec![a, b, a],
        None => {
            let back = next[first]
                .iter()
                .copied()
                .filter(|to| component.contains(to));
            let paths = back.map(|to| shortest_path(to, first, next));
            let mut cycle = vec![first];
            cycle.extend(paths.min_by_key(Vec::len).unwrap_or_default());
            cycle
        }
    };
    let level = std::iter::once("crate")
        .chain(level.iter().map(String::as_str))
        .collect::<Vec<_>>()
        .join("::");
    let names: Vec<String> = cycle.iter().map(|n| name(n)).collect();
    let mut text = format!("at `{level}`: {}", names.join(" -> "));
    for pair in cycle.windows(2) {
        let (from, to) = (pair[0], pair[1]);
        text += &format!(
            "\n    {} -> {}: {}",
            name(from),
            name(to),
            example(from, to)
        );
    }
    if component.len() + 1 > cycle.len() {
        let all: Vec<String> = component.iter().map(|n| name(n)).collect();
        text += &format!("\n    in the cycle of {}", all.join(", "));
        for &(a, b) in pairs.iter().skip(1) {
            text += &format!(
                "\n    {} <-> {}: {}; {}",
                name(a),
                name(b),
                example(a, b),
                example(b, a)
            );
        }
    }
    text
}

/// The crates' roots, from the top of the repository.
const CRATE_ROOTS: [&str; 4] = [
    "crates/core/src/lib.rs",
    "crates/server/src/lib.rs",
    "crates/eval/src/lib.rs",
    "src/main.rs",
];

fn repository() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// README's layout table names paths that exist, every crate, and every top module of each.
#[test]
fn the_readme_layout_table_names_every_crate_and_top_module() {
    let readme = fs::read_to_string(repository().join("README.md")).unwrap();
    let listed = layout_table_paths(&readme);
    let missing: Vec<&String> = listed
        .iter()
        .filter(|path| !repository().join(path).exists())
        .collect();
    assert!(missing.is_empty(), "listed but missing: {missing:?}");
    let names = |path: &str| {
        listed
            .iter()
            .any(|l| l == path || l.starts_with(&format!("{}/", path.trim_end_matches('/'))))
    };
    for root in CRATE_ROOTS {
        let (dir, _) = root.rsplit_once('/').unwrap();
        if let Some(krate) = dir.strip_suffix("/src") {
            assert!(names(&format!("{krate}/")), "crate {krate} is not listed");
        }
        let text = fs::read_to_string(repository().join(root)).unwrap();
        for line in text.lines().map(str::trim) {
            let Some(module) = line
                .strip_prefix("pub mod ")
                .or_else(|| line.strip_prefix("mod "))
                .and_then(|rest| rest.strip_suffix(';'))
            else {
                continue;
            };
            assert!(
                names(&format!("{dir}/{module}.rs")) || names(&format!("{dir}/{module}/")),
                "{dir}/{module} is not listed"
            );
        }
    }
}

#[test]
fn no_crate_has_an_import_cycle() {
    for root in CRATE_ROOTS {
        let cycles = module_cycles(&repository().join(root));
        assert!(cycles.is_empty(), "{root}:\n{}", cycles.join("\n"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A crate's `src` directory in a fresh temporary directory, removed on drop.
    struct FakeCrate(PathBuf);

    impl FakeCrate {
        fn new(files: &[(&str, &str)]) -> FakeCrate {
            static COUNT: AtomicUsize = AtomicUsize::new(0);
            let dir = std::env::temp_dir().join(format!(
                "layout-check-{}-{}",
                std::process::id(),
                COUNT.fetch_add(1, Ordering::Relaxed)
            ));
            for (path, text) in files {
                let path = dir.join(path);
                fs::create_dir_all(path.parent().unwrap()).unwrap();
                fs::write(path, text).unwrap();
            }
            FakeCrate(dir)
        }

        fn cycles(&self) -> Vec<String> {
            module_cycles(&self.0.join("lib.rs"))
        }
    }

    impl Drop for FakeCrate {
        fn drop(&mut self) {
            let _ = fs::remove_dir_all(&self.0);
        }
    }

    fn first_lines(cycles: &[String]) -> Vec<&str> {
        cycles.iter().map(|c| c.lines().next().unwrap()).collect()
    }

    #[test]
    fn acyclic_tree_has_no_cycles() {
        let fake = FakeCrate::new(&[
            (
                "lib.rs",
                "pub mod a;\npub mod b;\npub mod c;\npub use b::Thing;\n",
            ),
            ("a.rs", "use std::fmt;\npub struct A;\n"),
            (
                "b/mod.rs",
                "mod inner;\nuse crate::a::A;\npub use inner::Thing;\n",
            ),
            ("b/inner.rs", "use crate::a::A;\npub struct Thing(A);\n"),
            (
                "c.rs",
                "use crate::{a::A, b::Thing};\nfn f() -> crate::Thing { todo!() }\n",
            ),
        ]);
        assert_eq!(fake.cycles(), Vec::<String>::new());
    }

    #[test]
    fn sibling_cycle_is_reported_with_examples() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "pub mod a;\npub mod b;\n"),
            ("a.rs", "use crate::b::X;\npub struct Y;\n"),
            (
                "b.rs",
                "\n\nuse crate::a::Y;\npub struct X(Y);\nfn f() { crate::a::g(); }\n",
            ),
        ]);
        assert_eq!(
            fake.cycles(),
            [
                "at `crate`: a -> b -> a\n    a -> b: a.rs:1 `crate::b::X`\n    \
              b -> a: b.rs:3 `crate::a::Y` (+1 more)"
            ]
        );
    }

    #[test]
    fn a_module_and_its_children_are_one_unit() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "#[cfg(feature = \"server\")]\npub mod api;\n"),
            (
                "api/mod.rs",
                "mod models;\npub(crate) mod ops;\n\npub struct App;\n\
                 fn router() { route(\"/\", models::add_model); }\n",
            ),
            ("api/models.rs", "use super::App;\npub fn add_model() {}\n"),
            ("api/ops.rs", "use super::App;\n"),
        ]);
        assert!(fake.cycles().is_empty(), "{:?}", fake.cycles());
    }

    #[test]
    fn child_modules_of_a_file_module() {
        // `rank.rs` with `rank/columns.rs` and `rank/arrange.rs`, used by relative paths.
        let fake = FakeCrate::new(&[
            ("lib.rs", "pub mod rank;\n"),
            (
                "rank.rs",
                "mod arrange;\nmod columns;\nuse columns::Row;\nstruct Compared;\n",
            ),
            (
                "rank/columns.rs",
                "use super::Compared;\nuse super::arrange::order;\npub struct Row;\n",
            ),
            (
                "rank/arrange.rs",
                "pub fn order(r: super::columns::Row) {}\n",
            ),
        ]);
        assert_eq!(
            fake.cycles(),
            ["at `crate::rank`: arrange -> columns -> arrange\n    \
              arrange -> columns: rank/arrange.rs:1 `super::columns::Row`\n    \
              columns -> arrange: rank/columns.rs:2 `super::arrange::order`"]
        );
    }

    #[test]
    fn re_exports_lead_to_the_defining_module() {
        let fake = FakeCrate::new(&[
            (
                "lib.rs",
                "pub mod error;\npub mod mesh;\npub use error::Error;\n",
            ),
            ("error.rs", "pub struct Error;\n"),
            (
                "mesh.rs",
                "use crate::Error;\nfn f() -> crate::Error { todo!() }\n",
            ),
        ]);
        assert_eq!(fake.cycles(), Vec::<String>::new());
        // …and a cycle through a re-export is one.
        let fake = FakeCrate::new(&[
            (
                "lib.rs",
                "pub mod error;\npub mod mesh;\npub use error::{Error, Result};\n",
            ),
            (
                "error.rs",
                "use crate::mesh::Format;\npub struct Error(Format);\n",
            ),
            ("mesh/mod.rs", "mod load;\npub use self::load::Format;\n"),
            ("mesh/load.rs", "use crate::Result;\npub enum Format {}\n"),
        ]);
        assert_eq!(
            fake.cycles(),
            ["at `crate`: error -> mesh -> error\n    \
              error -> mesh: error.rs:1 `crate::mesh::Format`\n    \
              mesh -> error: mesh/load.rs:1 `crate::Result`"]
        );
    }

    #[test]
    fn comments_strings_and_tests_are_ignored() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "pub mod a;\npub mod b;\n"),
            ("a.rs", "use crate::b::X;\n"),
            (
                "b.rs",
                "//! Uses [`crate::a::Y`].\n\
                 /// See `crate::a::Y`.\n\
                 // use crate::a::Y;\n\
                 /* crate::a::Y /* nested */ crate::a::Y */\n\
                 pub struct X;\n\
                 const S: &str = \"crate::a::Y\";\n\
                 const R: &str = r#\"super::a::Y \"quoted\" \"#;\n\
                 const C: char = '\"';\n\
                 fn f<'a>(x: &'a str) -> char { '\\'' }\n\
                 pub(in crate::a) fn g() {}\n\
                 #[cfg(test)]\n\
                 \n\
                 mod tests {\n    use crate::a::Y;\n    use super::*;\n}\n",
            ),
        ]);
        assert_eq!(fake.cycles(), Vec::<String>::new());
        // A `#[cfg(test)]` item that is not the tests module counts.
        let fake = FakeCrate::new(&[
            ("lib.rs", "pub mod a;\npub mod b;\n"),
            ("a.rs", "use crate::b::X;\n"),
            ("b.rs", "#[cfg(test)]\nfn helper() { crate::a::f(); }\n"),
        ]);
        assert_eq!(first_lines(&fake.cycles()), ["at `crate`: a -> b -> a"]);
    }

    #[test]
    fn grouped_multi_line_uses_with_nested_braces() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "pub mod a;\npub mod b;\npub mod d;\n"),
            ("a.rs", "pub struct X;\n"),
            ("b/mod.rs", "pub mod c;\npub struct W;\n"),
            ("b/c.rs", "pub struct Y;\npub struct Z;\nuse crate::d::Q;\n"),
            (
                "d.rs",
                "use crate::{\n    a::X,\n    b::{\n        c::{Y, Z as Zed},\n        W,\n    },\n};\n\
                 pub struct Q;\n",
            ),
        ]);
        assert_eq!(
            fake.cycles(),
            ["at `crate`: b -> d -> b\n    \
              b -> d: b/c.rs:3 `crate::d::Q`\n    \
              d -> b: d.rs:4 `crate::b::c::Y` (+2 more)"]
        );
    }

    #[test]
    fn super_super_and_self_paths() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "pub mod a;\n"),
            ("a/mod.rs", "pub mod x;\npub mod z;\n"),
            ("a/x/mod.rs", "pub mod y;\n"),
            (
                "a/x/y.rs",
                "pub fn g() -> super::super::z::Thing { Thing }\n",
            ),
            (
                "a/z.rs",
                "pub struct Thing;\nfn f() { crate::a::x::y::g(); }\n",
            ),
        ]);
        assert_eq!(
            fake.cycles(),
            ["at `crate::a`: x -> z -> x\n    \
              x -> z: a/x/y.rs:1 `super::super::z::Thing`\n    \
              z -> x: a/z.rs:2 `crate::a::x::y::g`"]
        );
    }

    #[test]
    fn undeclared_and_path_modules_are_not_modules() {
        let fake = FakeCrate::new(&[
            (
                "lib.rs",
                "pub mod a;\n#[path = \"elsewhere.rs\"]\nmod b;\n#[cfg(test)]\nmod tests;\n",
            ),
            ("tests.rs", "use crate::a::Z;\n"),
            (
                "a.rs",
                "use crate::b::X;\nuse crate::stray::Y;\nuse crate::tests::T;\n",
            ),
            ("b.rs", "use crate::a::Z;\n"),
            ("stray.rs", "use crate::a::Z;\n"),
        ]);
        assert_eq!(fake.cycles(), Vec::<String>::new());
    }

    #[test]
    fn longer_cycles_and_components() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "mod a;\nmod b;\nmod c;\nmod d;\nmod e;\n"),
            ("a.rs", "use crate::b::B;\n"),
            ("b.rs", "use crate::c::C;\n"),
            ("c.rs", "use crate::a::A;\n"),
            ("d.rs", "use crate::e::E;\n"),
            ("e.rs", "use crate::d::D;\nuse crate::a::A;\n"),
        ]);
        assert_eq!(
            fake.cycles(),
            [
                "at `crate`: a -> b -> c -> a\n    a -> b: a.rs:1 `crate::b::B`\n    \
                 b -> c: b.rs:1 `crate::c::C`\n    c -> a: c.rs:1 `crate::a::A`",
                "at `crate`: d -> e -> d\n    d -> e: d.rs:1 `crate::e::E`\n    \
                 e -> d: e.rs:1 `crate::d::D`",
            ]
        );
    }

    #[test]
    fn larger_components_list_their_nodes_and_pairs() {
        let fake = FakeCrate::new(&[
            ("lib.rs", "mod a;\nmod b;\nmod c;\n"),
            ("a.rs", "use crate::b::B;\n"),
            ("b.rs", "use crate::a::A;\nuse crate::c::C;\n"),
            ("c.rs", "use crate::b::B;\n"),
        ]);
        assert_eq!(
            fake.cycles(),
            [
                "at `crate`: a -> b -> a\n    a -> b: a.rs:1 `crate::b::B`\n    \
              b -> a: b.rs:1 `crate::a::A`\n    in the cycle of a, b, c\n    \
              b <-> c: b.rs:2 `crate::c::C`; c.rs:1 `crate::b::B`"
            ]
        );
    }

    #[test]
    fn tokens_skip_literals_and_lifetimes() {
        let source =
            "let a = 'x'; fn f<'a>() {} let b = b\"crate::x\"; r#type::y; '\\u{1F600}'; é::z";
        let tokens: Vec<String> = tokenize(source).into_iter().map(|t| t.text).collect();
        assert_eq!(
            tokens,
            [
                "let", "a", "=", ";", "fn", "f", "<", ">", "(", ")", "{", "}", "let", "b", "=",
                ";", "type", "::", "y", ";", ";", "é", "::", "z"
            ]
        );
    }

    const README: &str = "\
# salient

## Layout

The modules follow the pipeline:

| module | what |
|---|---|
| `src/mesh/load/` | OBJ (`tobj`), glTF |
| `src/mesh/weld.rs`, `orient.rs`, `simplify.rs` | weld, `meshopt` |
| `src/signature.rs` | the format; `signature/legacy.rs` reads old ones |
| `src/eval/`, `metrics.rs` | measures |
| `docker/` | the image |

| `src/not/this.rs` | a later table |

## Benchmarks

| `src/nor/this.rs` | x |
";

    #[test]
    fn layout_table_first_column() {
        assert_eq!(
            layout_table_paths(README),
            [
                "src/mesh/load/",
                "src/mesh/weld.rs",
                "src/mesh/orient.rs",
                "src/mesh/simplify.rs",
                "src/signature.rs",
                "src/eval/",
                "src/eval/metrics.rs",
                "docker/",
            ]
        );
    }

    #[test]
    fn layout_table_missing() {
        assert!(layout_table_paths("# x\n\n| `a.rs` | b |\n").is_empty());
        assert!(layout_table_paths("## Layout\n\nNo table.\n\n## Next\n| `a.rs` |\n").is_empty());
    }
}
