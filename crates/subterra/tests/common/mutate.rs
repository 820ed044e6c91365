//! Damage done to text files the way they get damaged (cut, spliced, a value replaced by an
//! absurd one), for the parser property tests of this crate and of `subterra-sim` (which
//! includes this file by path).

use proptest::prelude::*;

/// Tokens that break TOML or configs: syntax, absurd numbers, types of the wrong kind.
const TOKENS: &[&str] = &[
    "=", "[", "]", "[[", "]]", "\"", "'", "{", "}", ",", "\n", "#", ".", "nan", "-nan", "inf", "-inf", "1e308", "-1e308", "1e-320", "0", "-1",
    "-9223372036854775809", "18446744073709551616", "true", "\"x\"", "[]", "{}", "1979-05-27", "0x7fffffff", "é", "\u{0}", "\\u0000",
];

/// One edit of a text.
#[derive(Debug, Clone)]
pub enum Edit {
    Delete { at: usize, len: usize },
    Insert { at: usize, token: usize },
    ReplaceValue { line: usize, token: usize },
    DuplicateLine { line: usize },
    Truncate { at: usize },
}

/// Any edit.
pub fn edit_strategy() -> impl Strategy<Value = Edit> {
    prop_oneof![
        1 => (any::<usize>(), 1usize..40).prop_map(|(at, len)| Edit::Delete { at, len }),
        1 => (any::<usize>(), any::<usize>()).prop_map(|(at, token)| Edit::Insert { at, token }),
        3 => (any::<usize>(), any::<usize>()).prop_map(|(line, token)| Edit::ReplaceValue { line, token }),
        1 => any::<usize>().prop_map(|line| Edit::DuplicateLine { line }),
        1 => any::<usize>().prop_map(|at| Edit::Truncate { at }),
    ]
}

/// The nearest char boundary at or below `at % (len + 1)`.
fn boundary(text: &str, at: usize) -> usize {
    let mut i = at % (text.len() + 1);
    while !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// `text` with `edit` applied.
pub fn apply(text: &str, edit: &Edit) -> String {
    let lines: Vec<&str> = text.lines().collect();
    match *edit {
        Edit::Delete { at, len } => {
            let a = boundary(text, at);
            let b = boundary(text, a + len.min(text.len() - a));
            format!("{}{}", &text[..a], &text[b.max(a)..])
        }
        Edit::Insert { at, token } => {
            let a = boundary(text, at);
            format!("{}{}{}", &text[..a], TOKENS[token % TOKENS.len()], &text[a..])
        }
        Edit::ReplaceValue { line, token } => {
            let i = line % lines.len().max(1);
            let mut out: Vec<String> = lines.iter().map(ToString::to_string).collect();
            if let Some(l) = out.get_mut(i) {
                if let Some(eq) = l.find('=') {
                    *l = format!("{}= {}", &l[..eq], TOKENS[token % TOKENS.len()]);
                }
            }
            out.join("\n")
        }
        Edit::DuplicateLine { line } => {
            let i = line % lines.len().max(1);
            let mut out: Vec<&str> = lines.clone();
            if let Some(l) = lines.get(i) {
                out.insert(i, l);
            }
            out.join("\n")
        }
        Edit::Truncate { at } => text[..boundary(text, at)].to_string(),
    }
}

