// Table-driven random forests (emlearn style): a model is data, walked by one small function.
//
// Split nodes and leaves are stored apart (a leaf needs neither a feature nor a child index), in parallel
// arrays so each stays naturally aligned; a tree's split nodes and its leaves are each in preorder:
//   split node (7 bytes):
//     feature u8    bits 0-5 the input index; kLeftLeaf: the left child is a leaf; kRightLeaf: the right one is
//     value f32     split threshold: go left when x[feature] <= value
//     skip u16      the leaves under the left child. Walking, the left child is split node i + 1 or leaf l
//                   (l: the leaf cursor, the first leaf under node i), the right child split node i + skip or
//                   leaf l + skip (in preorder a left subtree of n leaves holds n - 1 split nodes)
//   leaf (2 bytes): leaf u16, the index of its value in leaf_value (the forest's distinct leaf values, f32:
//                   the values exactly, each once)
// Tree t's split nodes start at roots[t], its leaves at roots[t] + t (a tree has one leaf more than split
// nodes; a tree of a single leaf is exported as one split node with two leaves of that value).
// Regressors: leaf value = the tree's prediction; the forest averages them.
// Binary classifiers: leaf value = P(class 1); class 1 when the forest's mean exceeds 0.5 (argmax with
// ties to class 0, as scikit-learn's soft vote).
// Thresholds are scikit-learn's float64 split points rounded DOWN to float32, so `x <= t` on float32
// inputs decides exactly as scikit-learn's comparison of the float32-cast input with the float64 split.
#pragma once

#include <stdint.h>

namespace impactapp {

constexpr uint8_t kLeaf = 0xFF;         // linear_terms: an unused factor slot
constexpr uint8_t kInputMask = 0x3F;    // feature: the input index
constexpr uint8_t kLeftLeaf = 0x40;     // feature: the left child is a leaf
constexpr uint8_t kRightLeaf = 0x80;    // feature: the right child is a leaf

struct ForestTables {
  int32_t n_trees;
  const int32_t* roots;       // [n_trees] each tree's first split node (its first leaf: roots[t] + t)
  const uint8_t* feature;     // [n_splits]
  const float* value;         // [n_splits]
  const uint16_t* skip;       // [n_splits]
  const uint16_t* leaf;       // [n_splits + n_trees]
  const float* leaf_value;    // [distinct leaf values]
};

// Mean of the trees' leaf values for feature vector x.
float forest_mean(const ForestTables& f, const float* x);

// A linear model in the same arrays (host height_class.linear_tables; the energy class of a model whose card
// chose the linear estimate of log m g h): n_trees terms; term t's factors are feature[roots[t] ..
// roots[t] + 2] (input positions, kLeaf: none); value = [coef (n_trees), bias, offset_0, scale_0, offset_1,
// scale_1, ...]. Returns 0.5 + bias + sum_t coef_t * prod((x[f] - offset_f) * scale_f), so that > 0.5 is
// class 1 as for a classifier forest; skip, leaf and leaf_value are unused.
float linear_terms(const ForestTables& f, const float* x);

}  // namespace impactapp
