// Table-driven random forests (emlearn style): a model is data, walked by one small function.
//
// Split nodes and leaves are stored apart (a leaf needs neither a feature nor a child index), in parallel
// arrays so each stays naturally aligned; a tree's split nodes and its leaves are each in preorder:
//   split node (7 bytes):
//     feature u8      the input index
//     threshold i32   order_key of the float32 split threshold: go left when order_key(x[feature]) <= threshold,
//                     i.e. x[feature] <= the threshold (an integer compare: no FPU compare and status move)
//     skip u16        the leaves under the left child. In preorder a subtree of n leaves holds n - 1 split
//                     nodes, so from split node i with leaf cursor l (its first leaf) the left child is split
//                     node i + 1 or leaf l, the right child split node i + skip or leaf l + skip; a child with
//                     no split node under it is a leaf (the walk counts the split nodes left under it)
//   leaf (2 bytes):   leaf u16, the index of its value in leaf_value (the forest's distinct leaf values, f32:
//                     the values exactly, each once)
// Tree t's split nodes are roots[t] .. roots[t + 1] - 1, its leaves from roots[t] + t (a tree has one leaf more
// than split nodes; a tree of a single leaf is exported as one split node with two leaves of that value).
// Regressors: leaf value = the tree's prediction; the forest averages them.
// Binary classifiers: leaf value = P(class 1); class 1 when the forest's mean exceeds 0.5 (argmax with
// ties to class 0, as scikit-learn's soft vote).
// Thresholds are scikit-learn's float64 split points rounded DOWN to float32 (and -0 to +0), so the compare on
// float32 inputs decides exactly as scikit-learn's comparison of the float32-cast input with the float64 split.
#pragma once

#include <stdint.h>
#include <string.h>

namespace impactapp {

constexpr int kMaxModelInputs = 32;
constexpr uint8_t kLeaf = 0xFF;   // linear_terms: an unused factor slot

// A float's bits as an int32 that orders as the floats do: for finite a, b (and +-inf) with a, b not both zero,
// a <= b exactly when order_key(a) <= order_key(b); -0 sits just below +0 (thresholds are never -0). A NaN
// has no place in that order: forest_mean's inputs are finite (TableModels' gather refuses NaN and inf).
inline int32_t order_key(float v) {
  uint32_t b;
  memcpy(&b, &v, sizeof b);
  return static_cast<int32_t>(b ^ ((0u - (b >> 31)) >> 1));   // negative: flip the magnitude bits
}

struct ForestTables {
  int32_t n_trees;
  const int32_t* roots;       // [n_trees + 1] tree t's split nodes: roots[t] .. roots[t + 1] - 1
  const uint8_t* feature;     // [n_splits]
  const int32_t* threshold;   // [n_splits]
  const uint16_t* skip;       // [n_splits]
  const uint16_t* leaf;       // [n_splits + n_trees]
  const float* leaf_value;    // [distinct leaf values]
  const float* value;         // a linear model's terms (linear_terms); null for a forest
  int32_t n_inputs;           // the inputs the model reads (<= kMaxModelInputs)
};

// Mean of the trees' leaf values for the model's inputs x (finite).
float forest_mean(const ForestTables& f, const float* x);

// A linear model in the same struct (host height_class.linear_tables; the energy class of a model whose card
// chose the linear estimate of log m g h): n_trees terms; term t's factors are feature[roots[t] ..
// roots[t] + 2] (input positions, kLeaf: none); value = [coef (n_trees), bias, offset_0, scale_0, offset_1,
// scale_1, ...]. Returns 0.5 + bias + sum_t coef_t * prod((x[f] - offset_f) * scale_f), so that > 0.5 is
// class 1 as for a classifier forest; the forest arrays are null.
float linear_terms(const ForestTables& f, const float* x);

}  // namespace impactapp
